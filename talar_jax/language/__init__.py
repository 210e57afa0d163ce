"""Language layer: instruction sets, a flax BERT encoder for Hugging Face BERT folders, and the embedding cache."""

from talar_jax.language.augment import paraphrase_variants
from talar_jax.language.bert import BertConfig, BertModel, mean_pool
from talar_jax.language.cache import (
    SENTENCE_READOUTS,
    TOKEN_READOUT,
    TOKEN_SLOTS,
    TRANSLATOR_READOUTS,
    EmbeddingCache,
    build_cache,
    cached_sentence_features,
    default_cache_dir,
    features_with_cache,
    max_word_pieces,
    readout_features,
    sentence_features,
    stack_features,
)
from talar_jax.language.encoder import BertEncoder, EncoderError, default_encoder_path, load_encoder
from talar_jax.language.instructions import (
    DEVELOPMENT_FILE,
    InstructionFormat,
    InstructionSet,
    load_instructions,
    load_user_instructions,
    register_instruction_format,
)

__all__ = [
    "DEVELOPMENT_FILE",
    "SENTENCE_READOUTS",
    "TOKEN_READOUT",
    "TOKEN_SLOTS",
    "TRANSLATOR_READOUTS",
    "BertConfig",
    "BertEncoder",
    "BertModel",
    "EmbeddingCache",
    "EncoderError",
    "InstructionFormat",
    "InstructionSet",
    "build_cache",
    "cached_sentence_features",
    "default_cache_dir",
    "features_with_cache",
    "max_word_pieces",
    "default_encoder_path",
    "load_encoder",
    "load_instructions",
    "load_user_instructions",
    "mean_pool",
    "paraphrase_variants",
    "register_instruction_format",
    "readout_features",
    "sentence_features",
    "stack_features",
]
