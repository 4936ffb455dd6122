"""MIKASA-Robo datasets: the dataset-name helper and the raw NPZ episode format.

* :mod:`mikasa_datasets.naming` — ``env_id_to_dataset_name``, ``is_dataset_name`` (spec §1).
* :mod:`mikasa_datasets.npz` — schema, atomic writers, checked readers, ``metadata.json``
  (spec §2-§3).
"""

from mikasa_datasets.naming import env_id_to_dataset_name, is_dataset_name
from mikasa_datasets.npz import (
    BATCHED_TMP_SUBDIR,
    DATA_NPZ_DIRNAME,
    SCHEMA,
    EpisodeFormatError,
    EpisodeInvariantError,
    EpisodeSummary,
    list_episode_files,
    make_episode,
    read_episode,
    read_episode_summary,
    read_metadata,
    task_dir,
    validate_episode,
    write_episode,
    write_metadata,
)

__version__ = "0.2.0"

__all__ = [
    "BATCHED_TMP_SUBDIR",
    "DATA_NPZ_DIRNAME",
    "SCHEMA",
    "EpisodeFormatError",
    "EpisodeInvariantError",
    "EpisodeSummary",
    "__version__",
    "env_id_to_dataset_name",
    "is_dataset_name",
    "list_episode_files",
    "make_episode",
    "read_episode",
    "read_episode_summary",
    "read_metadata",
    "task_dir",
    "validate_episode",
    "write_episode",
    "write_metadata",
]
