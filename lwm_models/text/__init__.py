"""Manual text: the project's description generator, the human-written file loader, split pools."""

from .generator import IDENTITY_SYNONYMS, MOVEMENT_CLAUSES, ROLE_NOUNS, add_typos, generate_descriptions
from .human import load_description_file, load_description_files
from .pools import DescriptionPools, PoolError, default_pools

__all__ = [
    "IDENTITY_SYNONYMS",
    "MOVEMENT_CLAUSES",
    "ROLE_NOUNS",
    "DescriptionPools",
    "PoolError",
    "add_typos",
    "default_pools",
    "generate_descriptions",
    "load_description_file",
    "load_description_files",
]
