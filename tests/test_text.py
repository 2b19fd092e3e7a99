"""The shared frozen text encoder loads offline and embeds meaning, not spelling."""

from cosmos_lite.text import get_text_encoder


def test_sentence_embeddings_rank_paraphrases_above_unrelated():
    enc = get_text_encoder()
    s = enc.sentences(["a red ball bounces on the floor", "a red ball is bouncing", "the stock market fell"])
    sim = s @ s.T
    assert sim[0, 1] > 0.8 and sim[0, 2] < 0.3


def test_token_embeddings_are_padded_and_cached():
    enc = get_text_encoder()
    emb, mask = enc.tokens(["push the block left", "hi"])
    assert emb.shape == (2, enc.max_length, enc.dim) and mask[1].sum() < mask[0].sum()
    again, _ = enc.tokens(["hi"])
    assert (again[0] == emb[1]).all()
