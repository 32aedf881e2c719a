"""Manual text: the project's description generator, the human-written file loader, split pools."""

from .generator import (
    IDENTITY_SYNONYMS,
    MOVEMENT_ADJECTIVES,
    MOVEMENT_CLAUSES,
    MOVEMENT_PHRASES,
    ROLE_NOUNS,
    ROLE_PHRASES,
    ROLE_PREDICATES,
    TEMPLATES,
    add_typos,
    generate_descriptions,
)
from .human import load_description_file, load_description_files
from .pools import (
    TRAIN_SHARE,
    UNSEEN_SHARE,
    DescriptionPools,
    PoolError,
    allocate,
    receiving_splits,
    split_counts,
)

__all__ = [
    "IDENTITY_SYNONYMS",
    "MOVEMENT_ADJECTIVES",
    "MOVEMENT_CLAUSES",
    "MOVEMENT_PHRASES",
    "ROLE_NOUNS",
    "ROLE_PHRASES",
    "ROLE_PREDICATES",
    "TEMPLATES",
    "TRAIN_SHARE",
    "UNSEEN_SHARE",
    "DescriptionPools",
    "PoolError",
    "add_typos",
    "allocate",
    "generate_descriptions",
    "load_description_file",
    "load_description_files",
    "receiving_splits",
    "split_counts",
]
