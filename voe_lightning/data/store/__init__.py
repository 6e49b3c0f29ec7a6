"""The store: procedurally generated records, sharded, compressed and read at random
(docs/architecture.md §5). ``root/manifest.json`` describes it; ``root/<concept>/<split>/
shard-NNNNN.voe`` hold the records. Its write path reads top-down, one step a module:

- ``generation``: ``generate_dataset`` (and ``ensure_dataset``) runs the steps below;
- ``plan``: the request checked and planned as a deterministic list of shards;
- ``manifest``: the manifest read, reconciled with the request, and written;
- ``verify``: each shard held against the plan (kept, regenerated or reported);
- ``render``: the missing shards rendered in worker processes (``workers``);
- ``shards``: the shard file, written and read (a record's bytes: ``codec``; written whole:
  ``files``).

Beside them: ``read`` (a split as a Dataset, for the DataModules), ``seeds`` (which seeds a split
draws; a seed offset's own store), ``layout`` (the splits, their seed ranges and the files'
names) and ``errors``. The names here are the store's public API."""

from voe_lightning.data.store.errors import (
    CorruptShardError,
    ManifestError,
    ManifestMismatchError,
)
from voe_lightning.data.store.files import (
    atomic_write,
    current_umask,
    remove_stale,
    temporary_prefix,
    write_whole,
)
from voe_lightning.data.store.generation import (
    GenerationSummary,
    ensure_dataset,
    generate_dataset,
)
from voe_lightning.data.store.layout import (
    GENERATOR_VERSION,
    MANIFEST_NAME,
    PROBE_SPLITS,
    SEED_OFFSET_FOLDER,
    SEED_RANGE,
    SEED_STARTS,
    SPLIT_RECORD_TYPE,
    SPLITS,
    shard_counts,
    shard_path,
)
from voe_lightning.data.store.manifest import (
    MANIFEST_KEYS,
    check_fresh_offset,
    draw_command,
    manifest_seed_offset,
    read_manifest,
    read_manifest_or_error,
    vocabulary,
    write_manifest,
)
from voe_lightning.data.store.plan import (
    DEFAULT_GENERALIZATION_PAIRS,
    DEFAULT_SHARD_SIZE,
    DEFAULT_TEST_PAIRS,
    DEFAULT_TRAIN_EXAMPLES,
    DEFAULT_VAL_PAIRS,
    ShardTask,
    plan_generation,
    plan_shards,
    shard_meta,
    split_counts,
)
from voe_lightning.data.store.read import (
    SplitDataset,
    collate,
    open_split,
    probe_sampler,
    record_loader,
)
from voe_lightning.data.store.seeds import (
    check_seed_offset,
    seed_offset_root,
    split_seeds,
    store_root,
)
from voe_lightning.data.store.shards import (
    FORMAT,
    ShardReader,
    check_shard,
    spec_layout,
    write_shard,
)
from voe_lightning.data.store.verify import (
    bad_shards,
    check_split,
    manifest_plan,
    record_layouts,
    verify,
)

__all__ = [
    # generating
    "generate_dataset",
    "ensure_dataset",
    "GenerationSummary",
    "plan_generation",
    "plan_shards",
    "split_counts",
    "shard_meta",
    "ShardTask",
    "check_fresh_offset",
    "DEFAULT_SHARD_SIZE",
    "DEFAULT_TRAIN_EXAMPLES",
    "DEFAULT_VAL_PAIRS",
    "DEFAULT_TEST_PAIRS",
    "DEFAULT_GENERALIZATION_PAIRS",
    # reading
    "open_split",
    "SplitDataset",
    "collate",
    "record_loader",
    "probe_sampler",
    # the manifest
    "read_manifest",
    "MANIFEST_KEYS",
    "read_manifest_or_error",
    "write_manifest",
    "draw_command",
    "manifest_seed_offset",
    "vocabulary",
    # checking a store against its plan
    "verify",
    "bad_shards",
    "check_split",
    "manifest_plan",
    "record_layouts",
    # seeds
    "check_seed_offset",
    "seed_offset_root",
    "split_seeds",
    "store_root",
    # the layout
    "SPLITS",
    "SPLIT_RECORD_TYPE",
    "PROBE_SPLITS",
    "SEED_STARTS",
    "SEED_RANGE",
    "SEED_OFFSET_FOLDER",
    "MANIFEST_NAME",
    "GENERATOR_VERSION",
    "shard_path",
    "shard_counts",
    # shard files, and files written whole
    "FORMAT",
    "write_shard",
    "ShardReader",
    "check_shard",
    "spec_layout",
    "atomic_write",
    "write_whole",
    "remove_stale",
    "temporary_prefix",
    "current_umask",
    # errors
    "CorruptShardError",
    "ManifestError",
    "ManifestMismatchError",
]
