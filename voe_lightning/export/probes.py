"""A store's probe split as an export reads it: the split's pairs grouped into quadruplets (the
two halves of one scene draw, docs/architecture.md §4) and lone pairs (a variant that is no
half, as continuity's ``paper`` or a generalization variant), each pair's videos named and
labelled, and records read one group at a time so a large split never sits in memory."""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.data import store

#: A pair's two videos, in the order every format writes them.
ROLES: tuple[str, str] = ("consistent", "inconsistent")
#: A quadruplet's videos by half and role: the first half is (A, AB), the second (B, BA).
LETTERS: tuple[tuple[str, str], tuple[str, str]] = (("A", "AB"), ("B", "BA"))
#: What IntPhys and IntPhys 2 call a consistent and an inconsistent video.
LABELS: dict[str, str] = {"consistent": "possible", "inconsistent": "impossible"}


@dataclass(frozen=True)
class ProbePair:
    """One probe record of the split: where it is (``index``), what it is, and, for a
    quadruplet's half, the quadruplet's row name and the half (0: A/AB, 1: B/BA)."""

    concept: str
    variant: str
    seed: int
    index: int
    quadruplet: str | None = None
    half: int | None = None

    @property
    def key(self) -> str:
        """The pair's name, unique in a split and free of dots (a WebDataset sample key)."""
        return f"{self.concept}_{self.seed}_{self.variant}"

    def video_name(self, role: str) -> str:
        """The name of the pair's ``role`` video: a quadruplet's by its letter (A, AB, B, BA),
        so the two halves' videos are told apart; a lone pair's by its role."""
        if self.quadruplet is None or self.half is None:
            return f"{self.key}_{role}"
        letter = LETTERS[self.half][ROLES.index(role)]
        return f"{self.concept}_{self.seed}_{self.quadruplet}_{letter}"


@dataclass(frozen=True)
class ProbeGroup:
    """What a benchmark calls a scene: a quadruplet (its two halves' pairs, ``quadruplet``
    its row name) or a lone pair (``quadruplet`` None)."""

    concept: str
    seed: int
    pairs: tuple[ProbePair, ...]
    quadruplet: str | None = None


@dataclass(frozen=True)
class ProbeSource:
    """The probe split of a store to export: its store manifest, the concepts that hold pairs
    in it and their groups, quadruplets first (by seed, then row), then lone pairs, and each
    concept's split as a Dataset (``datasets``)."""

    root: Path
    split: str
    manifest: dict[str, Any]
    groups: tuple[ProbeGroup, ...]
    datasets: dict[str, store.SplitDataset] = field(default_factory=dict, repr=False)

    @property
    def concepts(self) -> list[str]:
        """The concepts with pairs in the split, in export order."""
        return list(dict.fromkeys(group.concept for group in self.groups))

    @property
    def seed_offset(self) -> int:
        """The seed offset the store's probes were drawn at (0: the store's own)."""
        return store.manifest_seed_offset(self.manifest)

    @property
    def video(self) -> dict[str, Any]:
        """The store's video options (num_frames, height, width, duration, timestep)."""
        return cast(dict[str, Any], self.manifest["video"])

    @property
    def num_videos(self) -> int:
        """Videos in the split (two per pair): the progress bar's total."""
        return 2 * sum(len(group.pairs) for group in self.groups)

    def seeds(self, concept: str) -> dict[str, Any]:
        """The store's seed range and pairs per variant of ``concept``'s split."""
        entry = self.manifest["concepts"][concept]["splits"][self.split]
        return {k: entry[k] for k in ("seed_start", "seed_stop", "variants")}

    def records(self, group: ProbeGroup) -> list[TensorDictBase]:
        """The records of ``group``'s pairs, each checked to be the pair the plan says."""
        dataset = self.datasets[group.concept]
        records = [dataset[pair.index] for pair in group.pairs]
        for pair, record in zip(group.pairs, records):
            found = (specs.variant_name(record), int(record["seed"]))
            if found != (pair.variant, pair.seed):
                raise ValueError(
                    f"{self.root}: record {pair.index} of {pair.concept}'s {self.split} split is "
                    f"{found[0]} seed {found[1]}, its manifest plans {pair.variant} seed "
                    f"{pair.seed}; regenerate the store (generate --overwrite)"
                )
        return records

    def iterate(self) -> Iterator[tuple[ProbeGroup, list[TensorDictBase]]]:
        """Each group with its records, in order."""
        for group in self.groups:
            yield group, self.records(group)


def open_fresh_probes(
    root: str | os.PathLike[str], split: str, concepts: Sequence[str] | None, seed_offset: int
) -> ProbeSource:
    """``open_probes`` of the store at ``root`` (offset 0), or of the probes ``generate
    --seed_offset N`` drew beside it (``store.seed_offset_root``): refused unless that
    store records offset N and shares no seed with the root's (``check_fresh_offset``); a
    missing one named with the command that draws exactly it (``store.draw_command``)."""
    path = store.seed_offset_root(root, seed_offset)
    if not seed_offset:
        return open_probes(path, split, concepts)
    if store.read_manifest(path) is None:
        _check_split(split)
        names = list(dict.fromkeys(concepts or ()))
        for concept in names:
            specs.check_concept(concept)
        wanted = names or list((store.read_manifest(root) or {"concepts": {}})["concepts"])
        store.check_fresh_offset(root, seed_offset, [(c, split) for c in wanted])
        raise FileNotFoundError(
            f"no fresh probes at {path}: {path / store.MANIFEST_NAME} is missing; draw them "
            f"with `{store.draw_command(root, seed_offset, (split,), names)}`"
        )
    source = open_probes(path, split, concepts)
    if source.seed_offset != seed_offset:
        raise ValueError(
            f"{path} holds probes drawn at seed offset {source.seed_offset}, not the "
            f"{seed_offset} asked for (a store generated or copied into its place); draw "
            f"them with `{store.draw_command(root, seed_offset, (split,), source.concepts)} "
            "--overwrite`"
        )
    store.check_fresh_offset(root, seed_offset, [(c, split) for c in source.concepts])
    return source


def _check_split(split: str) -> None:
    """A ValueError naming the probe splits unless ``split`` is one."""
    if split not in store.PROBE_SPLITS:
        raise ValueError(
            f"split {split!r} holds no probe pairs; probe splits are: "
            f"{', '.join(store.PROBE_SPLITS)}"
        )


def open_probes(
    root: str | os.PathLike[str], split: str, concepts: Sequence[str] | None = None
) -> ProbeSource:
    """The probe ``split`` of the store at ``root`` for ``concepts`` (default: every concept
    it holds), its shards checked against its manifest first. A ValueError (or
    FileNotFoundError) names a bad split, concept or store, and a split with no pairs."""
    _check_split(split)
    root = Path(root)
    manifest = store.read_manifest_or_error(root)
    stored = manifest["concepts"]
    concepts = list(dict.fromkeys(concepts or [c for c in specs.CONCEPTS if c in stored]))
    for concept in concepts:
        specs.check_concept(concept)
        if concept not in stored:
            raise ValueError(
                f"concept {concept!r} was not generated in {root}; it holds: "
                f"{', '.join(stored) or 'none'}"
            )
    store.check_split(root, manifest, concepts, split)
    datasets = {concept: store.open_split(root, concept, split) for concept in concepts}
    items = planned_items(manifest, split)
    groups = []
    for concept in concepts:
        planned = items.get(concept, [])
        if len(planned) != len(datasets[concept]):
            raise ValueError(
                f"{root}: {concept}'s {split} split holds {len(datasets[concept])} records, its "
                f"manifest plans {len(planned)}; regenerate the store (generate --overwrite)"
            )
        groups += group_pairs(concept, planned)
    if not groups:
        raise ValueError(
            f"the {split} split of {root} holds no probe pairs for {', '.join(concepts)}; "
            "export another split, or generate this one"
        )
    return ProbeSource(root, split, manifest, tuple(groups), datasets)


def planned_items(manifest: dict[str, Any], split: str) -> dict[str, list[tuple[str, int]]]:
    """Per concept, the (variant, seed) of each record of ``split`` in store order, from the
    shard plan the manifest describes (so grouping reads no record)."""
    tasks, _ = store.manifest_plan(manifest)
    items: dict[str, list[tuple[str, int]]] = {}
    for task in sorted(tasks, key=lambda task: (task.concept, task.index)):
        if task.split == split:
            items.setdefault(task.concept, []).extend(task.items)
    return items


def group_pairs(concept: str, items: Sequence[tuple[str, int]]) -> list[ProbeGroup]:
    """``concept``'s records (their (variant, seed) in store order) as groups: every seed's
    two halves of a quadruplet row become one quadruplet, in (seed, row) order; every other
    record a lone pair, after them, in store order."""
    index = {item: number for number, item in enumerate(items)}
    quadruplets: list[ProbeGroup] = []
    halves: set[tuple[str, int]] = set()
    for seed in sorted({seed for _, seed in items}):
        for row, variants in specs.QUADRUPLETS.get(concept, {}).items():
            if all((variant, seed) in index for variant in variants):
                pairs = tuple(
                    ProbePair(concept, variant, seed, index[(variant, seed)], row, half)
                    for half, variant in enumerate(variants)
                )
                quadruplets.append(ProbeGroup(concept, seed, pairs, row))
                halves.update((variant, seed) for variant in variants)
    lone = [
        ProbeGroup(concept, seed, (ProbePair(concept, variant, seed, number),))
        for number, (variant, seed) in enumerate(items)
        if (variant, seed) not in halves
    ]
    return quadruplets + lone
