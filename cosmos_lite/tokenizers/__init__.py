"""Causal video tokenizer (continuous CV and FSQ discrete DV), its training, windowed inference and CLI."""

from .models import SIZES, VARIANTS, Tokenizer, TokenizerConfig, build_tokenizer, load_tokenizer, tokenizer_config

__all__ = ["SIZES", "VARIANTS", "Tokenizer", "TokenizerConfig", "build_tokenizer", "load_tokenizer",
           "tokenizer_config"]
