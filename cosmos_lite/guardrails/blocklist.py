"""Keyword pre-guard: whole-word blocklist matching that sees through obfuscation.

A prompt is folded (NFKC, zero-width removal, homoglyphs, case), separated letters are rejoined
("m.u.r.d.e.r", "d e c a p"), leetspeak is undone, every word is lemmatised in each configured
language (simplemma), and unknown words are fuzzy-matched to blocked words with an edit distance
scaled to the word's length. An allow-list masks benign uses ("kill switch", "grape") first.
Terms marked `~` have common harmless senses ("killer", "naked", "bomb"): written plainly, they block only when
a second opinion (the semantic guard's lenient threshold) agrees; disguised or misspelled, they always block.
Lists are editable text files per language in `data/blocklist/` and `data/allowlist/`.
Languages in `substring_languages` (Swedish, Russian, Chinese, Japanese, Arabic, Hindi) have lists of stems instead,
matched at word starts (anywhere in zh, ja, ar) in the prompt as written (look-alike letters of Latin kept, so Russian
is not read as broken Latin) and in its folded form (so a Russian word disguised with Latin letters is still found):
no lemmas, no misspellings.
"""

from __future__ import annotations

import itertools
import re
import unicodedata
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

from ..errors import ConfigError
from .core import Verdict

DATA_DIR = Path(__file__).resolve().parent / "data"

# Cyrillic, Greek and Armenian letters that look like Latin ones (after casefold; NFKC already maps full-width).
HOMOGLYPHS = str.maketrans({
    "а": "a", "в": "b", "е": "e", "ё": "e", "к": "k", "м": "m", "н": "h", "о": "o", "р": "p", "с": "c", "т": "t",
    "у": "y", "х": "x", "ѕ": "s", "і": "i", "ї": "i", "ј": "j", "ԁ": "d", "һ": "h", "ԛ": "q", "ԝ": "w", "ɡ": "g",
    "α": "a", "β": "b", "ε": "e", "η": "n", "ι": "i", "κ": "k", "ν": "v", "ο": "o", "ρ": "p", "τ": "t", "υ": "u",
    "χ": "x", "ω": "w", "ո": "n", "ս": "u", "օ": "o", "ɑ": "a", "ı": "i",
    "\u200b": None, "\u200c": None, "\u200d": None, "\u2060": None, "\ufeff": None, "\u00ad": None,
})
ZERO_WIDTH = str.maketrans({k: v for k, v in HOMOGLYPHS.items() if v is None})
# look-alike letters that are a language's own: in a prompt detected as Turkish, "ı" is a letter, not a disguise
# ("banyo bombası", bath bomb, is written plainly)
NATIVE_LOOKALIKES = {"tr": str.maketrans({"ı": "i"})}
LEET = {"0": "o", "1": "il", "2": "z", "3": "e", "4": "a", "5": "s", "6": "g", "7": "t", "8": "b", "9": "g",
        "@": "a", "$": "s", "!": "i", "|": "l", "€": "e"}
SEPARATORS = r"._\-*/·•~,+:"
SPELLED_OUT = re.compile(rf"^\w(?:[{SEPARATORS}]+\w){{2,}}$")  # m.u.r.d.e.r, k-i-l-l (3+ letters)
# combining marks belong to their word: Devanagari vowel signs and virama, Arabic harakat, Thai vowels, kana voicing
# (not matched by \w, which would cut "पुराना" into "प र न")
MARKS = ("\u0300-\u036f\u0483-\u0489\u0591-\u05c7\u0610-\u061a\u064b-\u065f\u0670\u06d6-\u06ed\u0900-\u0963"
         "\u0966-\u0dff\u0e31-\u0e4e\u3099\u309a")  # (not the Devanagari danda)
WORD = re.compile(rf"(?:[^\W_]|[{MARKS}]|[@$!|€])+")  # letters, digits, combining marks and leet symbols
EDGE = "\"'()[]{}<>.,;:?!¡¿«»“”‘’"
SUFFIXES = ("ing", "ed", "es", "s", "er", "en", "e", "ung")
# a Spanish or Italian gerund with its pronouns attached ("ahorcándose", "impiccandosi", "matándolo"), accents off:
# the lists hold the infinitive, alone or with the pronoun ("ahorcarse", "impiccarsi", "tagliarsi le vene")
ENCLITIC = re.compile(r"^(\w{3,}?)(a|ie|e|i)ndo(se|si|lo|la|le|los|las|les|li|gli|ne|me|mi|te|ti|nos|ci|vi)$")
INFINITIVES = {"a": ("ar", "are"), "ie": ("er", "ir"), "e": ("er", "ere", "ir", "ire"), "i": ("ir",)}
# substring languages whose stems match inside words too: written without spaces, or with clitics prefixed to words
# (Arabic "والهيروين", "and the heroin"); elsewhere a stem matches at the start of a word ("пытк", torture, is not the
# end of "попытка", attempt)
INSIDE_WORDS = ("zh", "ja", "ar")
# a capitalised word or a short acronym inside a sentence: a name ("Kill Van Kull", "MMA"), never read as a typo
NAME = re.compile(r"(?<=[^\s.!?:;]\s)(?:[A-Z][a-z]+|[A-Z]{2,4})\b")


@dataclass
class BlocklistConfig:
    """Which languages' lists and lemmatisers to use, and how loose the fuzzy matching is."""

    enabled: bool = True
    languages: list[str] = field(default_factory=lambda: ["en", "de", "fr", "es", "it", "pt", "nl", "pl", "tr", "sv",
                                                          "ru", "zh", "ja", "ar", "hi"])
    # listed languages whose entries are stems matched anywhere in the prompt, not lemmatised words: written without
    # spaces (zh, ja), with endings and clitics the lemmatiser does not cover (ru, ar, hi), or whose lemmatiser reads
    # other languages' words as its own (sv: Spanish "por" as "porr")
    substring_languages: list[str] = field(default_factory=lambda: ["sv", "ru", "zh", "ja", "ar", "hi"])
    compound_languages: list[str] = field(default_factory=lambda: ["de", "nl"])  # terms also match as a compound's end
    fuzzy: bool = True
    fuzzy_ratio: float = 0.25  # max edits = floor(ratio * len(blocked word)): 1 for 4-7 letters, 2 for 8-11
    fuzzy_min_len: int = 4  # shorter blocked words must match exactly
    # listed languages whose prompts are searched for misspellings; not Polish or Turkish, whose endings read as typos
    # (Turkish "Boğazı'nda" is not "nuda")
    fuzzy_languages: list[str] = field(default_factory=lambda: ["en", "de", "fr", "es", "it", "pt", "nl"])
    known_languages: list[str] = field(default_factory=lambda: ["en"])  # with the prompt's language: not typos
    capitalised_nouns: list[str] = field(default_factory=lambda: ["de"])  # capitals there do not mark names
    # languages without lists that a prompt may be written in: one detected as such is not searched for misspellings
    # (Swedish "göra" is not "gore"; its stems are not lemmatised, so it counts as unlisted here)
    unlisted_languages: list[str] = field(default_factory=lambda: ["sv"])
    data_dir: str | None = None  # folder with blocklist/<lang>.txt and allowlist/<lang>.txt; null: shipped lists


def deaccent(s: str) -> str:
    """Drop combining accents ("töten" -> "toten"), so accented and plain spellings match."""
    return "".join(c for c in unicodedata.normalize("NFKD", s) if not unicodedata.combining(c))


def fold(text: str) -> str:
    """NFKC, casefold, homoglyphs to Latin, zero-width characters removed."""
    return unicodedata.normalize("NFKC", text).casefold().translate(HOMOGLYPHS)


def fold_native(text: str) -> str:
    """`fold` with every letter kept in its own script: a Russian word stays Russian ("порно", not "пopho")."""
    return unicodedata.normalize("NFKC", text).casefold().translate(ZERO_WIDTH)


def chunks(text: str, folding: Callable[[str], str] = fold) -> list[tuple[str, bool]]:
    """Folded whitespace chunks, with letters written one by one rejoined ("d e c a p", "m.u.r.d.e.r");
    the flag says the chunk was spelled out (then blocked words are also looked for inside it)."""
    raw = [c.strip(EDGE) for c in folding(text).split()]
    raw = [c for c in raw if c and not re.fullmatch(rf"[{SEPARATORS}]+", c)]
    marked = [(re.sub(rf"[{SEPARATORS}]", "", c), True) if SPELLED_OUT.match(c) else (c, False) for c in raw]
    out: list[tuple[str, bool]] = []
    for single, run in itertools.groupby(marked, key=lambda c: len(c[0]) == 1):
        run = list(run)
        out += [("".join(c for c, _ in run), True)] if single and len(run) >= 3 else run
    return out


def words(text: str, folding: Callable[[str], str] = fold) -> list[str]:
    """Folded words (leet symbols kept inside words) with spelled-out words rejoined."""
    return [w for c, _ in chunks(text, folding) for w in WORD.findall(c)]


def spans(text: str, folding: Callable[[str], str]) -> str:
    """The prompt's words as one string for stem matching, " " before and after each (leetspeak undone, spelled-out
    words rejoined)."""
    return " " + " ".join(deleet(w)[0] for w in words(text, folding)) + " "


def readable(text: str) -> str:
    """The prompt with its disguise taken off: folded, spelled-out words rejoined, leetspeak undone ("Vid3o of a
    k-i-l-l" -> "video of a kill"); what the semantic guard reads."""
    return " ".join(WORD.sub(lambda m: deleet(m.group())[0], c) for c, _ in chunks(text))


def deleet(word: str) -> list[str]:
    """Readings of a word with leetspeak undone ("k1ll" -> kill, kill); words without letters are kept."""
    if not any(c in LEET for c in word) or not any(c.isalpha() for c in word):
        return [word]
    options = [LEET.get(c, c) for c in word]
    return ["".join(p) for p in itertools.islice(itertools.product(*options), 8)]


def edit_distance(a: str, b: str, limit: int) -> int:
    """Optimal-string-alignment distance (a transposition is one edit); returns limit + 1 once above limit."""
    if abs(len(a) - len(b)) > limit:
        return limit + 1
    prev2, prev = None, list(range(len(b) + 1))
    for i in range(1, len(a) + 1):
        cur = [i] + [0] * len(b)
        for j in range(1, len(b) + 1):
            cost = a[i - 1] != b[j - 1]
            cur[j] = min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + cost)
            if prev2 is not None and i > 1 and j > 1 and a[i - 1] == b[j - 2] and a[i - 2] == b[j - 1]:
                cur[j] = min(cur[j], prev2[j - 2] + 1)
        if min(cur) > limit:
            return limit + 1
        prev2, prev = prev, cur
    return prev[-1]


def first_words(phrases: list[tuple[str, ...]]) -> dict[str, list[int]]:
    """Indices of `phrases` by their first word, so a prompt is matched only against phrases that can start there."""
    index: dict[str, list[int]] = {}
    for k, phrase in enumerate(phrases):
        index.setdefault(phrase[0], []).append(k)
    return index


def starts(index: dict[str, list[int]], positions: list[frozenset[str]],
           extra: list | None = None) -> list[tuple[int, int]]:
    """(phrase index, position) pairs where a phrase of `index` can start: its first word among the position's word
    forms (or a `*`), or its index in `extra[i]`; sorted, so phrases come in list order, as a scan over all would."""
    pairs = set()
    for i, forms in enumerate(positions):
        pairs.update((k, i) for f in (*forms, "*") for k in index.get(f, ()))
        if extra:
            pairs.update((k, i) for k in extra[i])
    return sorted(pairs)


class Lemmas:
    """simplemma (lemmas, known words, language detection) over a dictionary cache that holds every language in use:
    simplemma's shared one keeps 8 loaded and reloads the others on every prompt, seconds each."""

    def __init__(self, languages: tuple[str, ...]):
        from simplemma import Lemmatizer
        from simplemma.language_detector import LanguageDetector, MostCommonTokenSampler, RelaxedMostCommonTokenSampler
        from simplemma.strategies import DefaultStrategy
        from simplemma.strategies.dictionaries import DefaultDictionaryFactory
        from simplemma.strategies.dictionary_lookup import DictionaryLookupStrategy
        from simplemma.utils import normalize_token

        factory = DefaultDictionaryFactory(cache_max_size=len(languages))
        strategy = DefaultStrategy(dictionary_factory=factory)
        self._lemmatizer = Lemmatizer(lemmatization_strategy=strategy)
        self._lookup, self._normalize = DictionaryLookupStrategy(factory), normalize_token
        self._detectors = [LanguageDetector(languages, sampler, strategy)
                           for sampler in (MostCommonTokenSampler(), RelaxedMostCommonTokenSampler())]

    def lemmatize(self, word: str, lang: str) -> str:
        return self._lemmatizer.lemmatize(word, lang=lang)

    def is_known(self, word: str, lang: str) -> bool:
        return self._lookup.get_lemma(self._normalize(word), lang) is not None

    def langdetect(self, text: str) -> tuple[str, float]:
        """The most likely language of `text` and its share of words (simplemma.langdetect's ranking and tie-break)."""
        ranked: list[tuple[str, float]] = []
        for detector in self._detectors:
            ranked = sorted(detector.proportion_in_each_language(text).items(), key=lambda x: (x[0] == "unk", -x[1]))
            if len(ranked) == 1 or ranked[0][1] != ranked[1][1]:
                break
        return ranked[0]


@dataclass
class Term:
    """One blocklist entry: its folded words (`*` any word), optional context group, section and language."""

    words: tuple[str, ...]
    context: str | None  # a group name: block only when one of its words is in the prompt
    category: str
    language: str
    text: str
    ambiguous: bool = False  # `~`: has harmless senses; a plain use needs a second opinion
    stem: bool = False  # a substring language's entry: matched anywhere in the prompt, not as whole words
    native: str = ""  # a stem as written (fold_native), matched against the prompt as written


class Hit(NamedTuple):
    """A blocked term found in a prompt: the words it matched, and whether they were written plainly (no leetspeak,
    look-alike letters, separators or misspelling)."""

    term: Term
    matched: str
    plain: bool

    @property
    def needs_second_opinion(self) -> bool:
        """An ambiguous term written plainly: it blocks only if the second opinion agrees."""
        return self.term.ambiguous and self.plain


def _norm_phrase(text: str) -> tuple[str, ...]:
    """A list entry as a tuple of folded words; `*` (any one word) kept."""
    return tuple(w for part in text.split() for w in (["*"] if part == "*" else map(deaccent, words(part))))


@lru_cache(maxsize=4)
def shared_lemmas(languages: tuple[str, ...]) -> Lemmas:
    """One Lemmas per language set for the whole process: its dictionaries load once (seconds per language), however
    many guards are built."""
    return Lemmas(languages)


def load_lists(data_dir: Path, languages: list[str], substring_languages: list[str] = ()
               ) -> tuple[list[Term], list[tuple[str, ...] | str], dict[str, set[str]]]:
    """Parse the blocklist and allow-list files of `languages` into terms, allowed phrases and context groups; the
    entries of `substring_languages` become stems (Term.stem; their allowed phrases are kept as written, `" "` + the
    phrase's words, a string, not a tuple of words)."""
    terms, allowed, groups = [], [], {}
    for lang in languages:
        block, allow = data_dir / "blocklist" / f"{lang}.txt", data_dir / "allowlist" / f"{lang}.txt"
        if not block.is_file():
            raise ConfigError(f"no blocklist {block} for language {lang!r}; add the file or drop {lang} from "
                              "guardrails.blocklist.languages")
        category = "blocked"
        for line in block.read_text(encoding="utf-8").splitlines():
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            if line.startswith("[") and line.endswith("]"):
                category = line[1:-1]
            elif line.startswith("@") and ":" in line:
                name, members = line.split(":", 1)
                groups.setdefault(name.strip(), set()).update(deaccent(w) for w in words(members))
            else:
                parts = line.split()
                ambiguous = parts[-1] == "~"
                parts = parts[:-1] if ambiguous else parts
                context = parts.pop() if parts[-1].startswith("@") else None
                text = " ".join(parts)
                if lang in substring_languages:
                    if context:
                        raise ConfigError(f"{block}: {line!r}: a stem of a substring language takes no @group")
                    start = "" if lang in INSIDE_WORDS else " "
                    terms.append(Term((start + " ".join(words(text)),), None, category, lang, text, ambiguous, True,
                                      start + " ".join(words(text, fold_native))))
                else:
                    terms.append(Term(_norm_phrase(text), context, category, lang, text, ambiguous))
        if allow.is_file():
            for line in allow.read_text(encoding="utf-8").splitlines():
                line = line.split("#", 1)[0].strip()
                if line and lang in substring_languages:
                    allowed.append(" ".join(words(line, fold_native)))
                elif line:
                    allowed.append(_norm_phrase(line))
    missing = {t.context for t in terms if t.context and t.context not in groups}
    if missing:
        raise ConfigError(f"blocklist uses undefined group(s) {', '.join(sorted(missing))} in {data_dir}/blocklist")
    return terms, allowed, groups


class BlocklistGuard:
    """Blocks prompts containing a blocked word or phrase in any configured language, however disguised.
    `confirm(text) -> Verdict` is the second opinion on plainly written ambiguous terms; without one they block."""

    name = "blocklist"

    def __init__(self, cfg: BlocklistConfig | None = None, confirm: Callable[[str], Verdict] | None = None):
        self.cfg = cfg or BlocklistConfig()
        self.confirm = confirm
        substring = [x for x in self.cfg.languages if x in self.cfg.substring_languages]
        self.langs = tuple(x for x in self.cfg.languages if x not in substring)  # lemmatised, whole words
        self.detect = self.langs + tuple(x for x in self.cfg.unlisted_languages if x not in self.langs)
        self._lemmas = shared_lemmas(self.detect + tuple(x for x in self.cfg.known_languages if x not in self.detect))
        data_dir = Path(self.cfg.data_dir) if self.cfg.data_dir else DATA_DIR
        terms, allowed, self.groups = load_lists(data_dir, list(self.cfg.languages), substring)
        self.terms, self.stems = [t for t in terms if not t.stem], [t for t in terms if t.stem]
        self.allowed = [a for a in allowed if isinstance(a, tuple)]
        self.allowed_stems = [a for a in allowed if isinstance(a, str)]
        self.allowed_words = {p[0] for p in self.allowed if len(p) == 1}
        self.terms_by_first = first_words([t.words for t in self.terms])
        self.allowed_by_first = first_words(self.allowed)
        self.single = {t.words[0] for t in self.terms if len(t.words) == 1}
        self.compounds = [w for t in self.terms if len(t.words) == 1 and t.language in self.cfg.compound_languages
                          for w in t.words if len(w) >= 5]
        vocab = {w for t in self.terms for w in t.words if len(w) >= self.cfg.fuzzy_min_len}
        # fuzzy targets: blocked words and their common inflections -> (the blocked word, allowed edits). A form that
        # is itself a blocked word keeps that word's edits; one that inflects several ("matarlos" of "matarlo") the
        # fewest of theirs, so the set's iteration order (which changes per process) never decides a verdict.
        edits = {w: int(self.cfg.fuzzy_ratio * len(w)) for w in vocab}
        inflected: dict[str, tuple[str, int]] = {}
        for w in sorted(vocab):
            for form in (w + "s", w + "ed", w + "ing", w.rstrip("e") + "ing", w + "er"):
                if form not in inflected or edits[w] < inflected[form][1]:
                    inflected[form] = (w, edits[w])
        self.fuzzy_targets = inflected | {w: (w, k) for w, k in edits.items()}
        self.vocab = {w for t in self.terms for w in t.words}
        self.joined = {"".join(t.words) for t in self.terms if len("".join(t.words)) >= 3}
        self.known = tuple(self.cfg.known_languages)
        self._forms = lru_cache(maxsize=65536)(self._word_forms)
        self._typos = lru_cache(maxsize=65536)(self._typo_forms)

    def _inside(self, word: str) -> frozenset[str]:
        """Blocked terms (words joined) hidden inside a spelled-out word such as "acarbomb"."""
        variants = deleet(word)
        return frozenset(j for j in self.joined if any(j in v for v in variants))

    def _fuzzy(self, word: str) -> set[str]:
        stems = {word} | {word[: -len(s)] for s in SUFFIXES if word.endswith(s) and len(word) - len(s) >= 3}
        hits = set()
        for stem in stems:
            for form, (target, k) in self.fuzzy_targets.items():
                if k and edit_distance(stem, form, k) <= k:
                    hits.add(target)
        return hits

    def _word_forms(self, word: str) -> frozenset[str]:
        """All readings of one folded word: leet variants, accents off, lemmas per language, compounds, fuzzy. A word
        of a known language is lemmatised only in it: other languages' lemmatisers read English words as their own
        inflections (Spanish "violar" from "violin", Portuguese "suicidar" from "suicide")."""
        forms = set()
        for v in deleet(word):
            forms |= {v, deaccent(v)}
            known = [lang for lang in self.known if self._lemmas.is_known(v, lang)]
            for lang in known or self.langs:
                lemma = self._lemmas.lemmatize(v, lang).casefold()
                forms |= {lemma, deaccent(lemma)}
        forms |= {t for f in list(forms) for t in self.compounds if f.endswith(t) and len(f) >= len(t) + 3}
        for m in filter(None, map(ENCLITIC.match, list(forms))):
            stem, vowel, pronoun = m.groups()
            forms |= {form for ending in INFINITIVES[vowel] for form in (stem + ending, stem + ending[:-1] + pronoun)
                      if form in self.vocab}
        for f in list(forms):  # inflections the lemmatiser reads as other words ("cutting", "bombing")
            for s in SUFFIXES:
                stem = f[: -len(s)]
                if f.endswith(s) and len(stem) >= 3:
                    forms |= {stem, stem[:-1]} & self.vocab if stem[-1:] == stem[-2:-1] else {stem} & self.vocab
        return frozenset(forms)

    def _typo_forms(self, word: str, known: tuple[str, ...]) -> frozenset[str]:
        """Blocked words that `word` misspells, unless already blocked, allowed, or a word of a `known` language."""
        forms = self._forms(word)
        if not self.cfg.fuzzy or forms & self.single or forms & self.allowed_words or any(c.isdigit() for c in word):
            return forms
        typos = set()
        for v in deleet(word):
            if len(v) >= 3 and not any(self._lemmas.is_known(v, lang) for lang in known):
                typos |= self._fuzzy(deaccent(v))
        return forms | typos

    @staticmethod
    def _match(phrase: tuple[str, ...], positions: list[frozenset[str]], start: int) -> bool:
        if start + len(phrase) > len(positions):
            return False
        return all(w == "*" or w in positions[start + i] for i, w in enumerate(phrase))

    def hits(self, text: str) -> Iterator[Hit]:
        """Every blocked term in `text` that no allow-list entry covers, in list order, with the words it matched."""
        items = [(w, spelled) for c, spelled in chunks(text) for w in WORD.findall(c)]
        surface = [w for w, _ in items]
        # misspellings are looked for only in a prompt of a listed language, and neither a word of that language
        # ("roten" in German is not "töten"; Swedish "kall" is not "kill") nor a name ("Costa Rican") is a typo
        lang, share = self._lemmas.langdetect(text)
        names = set() if lang in self.cfg.capitalised_nouns else {fold(n) for n in NAME.findall(text)}
        if share >= 0.5 and lang in self.langs and lang in self.cfg.fuzzy_languages:
            known = tuple(sorted({*self.cfg.known_languages, lang}))
            positions = [self._forms(w) if w in names else self._typos(w, known) for w in surface]
        else:
            positions = [self._forms(w) for w in surface]
        inside = [self._inside(w) if spelled else frozenset() for w, spelled in items]
        # plain: no look-alike characters anywhere, a word of letters only, not spelled out, not read as a typo
        written = unicodedata.normalize("NFKC", text).casefold()
        if share >= 0.5 and lang in NATIVE_LOOKALIKES:
            written = written.translate(NATIVE_LOOKALIKES[lang])
        undisguised = fold(text) == written
        masked = set()
        for k, i in starts(self.allowed_by_first, positions):
            if self._match(self.allowed[k], positions, i):
                masked.update(range(i, i + len(self.allowed[k])))
        # a context word inside an allowed phrase does not count ("pieds nus", barefoot, is not sexual context)
        everything = set().union(*(f for i, f in enumerate(positions) if i not in masked))
        every_term = range(len(self.terms))
        for k, i in starts(self.terms_by_first, positions, [every_term if spelled else () for spelled in inside]):
            term = self.terms[k]
            if term.context and not self.groups[term.context] & everything:
                continue
            span = range(i, i + len(term.words))
            if not masked.intersection(span) and self._match(term.words, positions, i):
                plain = undisguised and all(
                    surface[j].isalpha() and not items[j][1] and (w == "*" or w in self._forms(surface[j]))
                    for j, w in zip(span, term.words))
                yield Hit(term, " ".join(surface[j] for j in span), plain)
            elif "".join(term.words) in inside[i]:
                yield Hit(term, surface[i], False)
        yield from self._stem_hits(text, lang if share >= 0.5 else None)

    def _stem_hits(self, text: str, lang: str | None) -> Iterator[Hit]:
        """Stems of the substring languages in `text`, written as is or disguised with look-alike letters (a stem
        whose folded form is plain Latin is looked for only as written: Russian "мет" folds to "met"), outside the
        allowed phrases. A stem of a language the detector knows (Swedish) counts only in a prompt detected as that
        language `lang`: Swedish "bomb" and "heroin" are also English words, with English allowed phrases."""
        stems = [t for t in self.stems if t.language not in self.detect or t.language == lang]
        if not stems:
            return
        native, folded = spans(text, fold_native), spans(text, fold)
        plain = " " + " ".join(WORD.findall(unicodedata.normalize("NFKC", text).casefold())) + " "
        for allowed in self.allowed_stems:
            native, plain, folded = native.replace(allowed, " "), plain.replace(allowed, " "), folded.replace(
                fold(allowed), " ")
        for term in stems:
            if term.native in native:
                yield Hit(term, term.native.strip(), term.native in plain)
            elif not term.words[0].isascii() and term.words[0] in folded:
                yield Hit(term, term.words[0].strip(), False)

    def find(self, text: str) -> Hit | None:
        """The hit that decides: the first one that blocks outright, else the first plain ambiguous one."""
        first = None
        for hit in self.hits(text):
            if not hit.needs_second_opinion:
                return hit
            first = first or hit
        return first

    def check(self, text: str) -> Verdict:
        hit = self.find(text)
        if hit is None:
            return Verdict(True, self.name, "no blocked term")
        term = hit.term
        where = f" with {term.context}" if term.context else ""
        reason = f"blocked term {term.text!r}{where} ({term.category}, {term.language}) matched {hit.matched!r}"
        if hit.needs_second_opinion and self.confirm is not None:
            second = self.confirm(text)
            if second.allowed:
                return Verdict(True, self.name, f"ambiguous term {term.text!r} matched {hit.matched!r}, read as "
                                                f"harmless ({second.guard}: {second.reason})")
            reason += f", ambiguous and confirmed ({second.guard}: {second.reason})"
        return Verdict(False, self.name, reason, term.category)
