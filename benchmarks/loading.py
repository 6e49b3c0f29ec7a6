"""Loading throughput (docs/architecture.md §10): records per second read from the store through
the DataLoader the DataModules use (decompression, checksum, TensorDict collation), for training
clips and probe pairs, with 0 and 2 worker processes. It must outrun training by a wide margin.

Run: ``python benchmarks/loading.py [--root data/bench_loading] [--records 512]`` (generates a
small store there first if missing)."""

from __future__ import annotations

import argparse
import os
import platform
import time

from torch.utils.data import DataLoader

from voe_lightning.data.store import collate, ensure_dataset, open_split


def records_per_second(dataset, workers: int, batch_size: int, records: int) -> float:
    """Read ``records`` records (cycling over the dataset) and return the rate."""
    loader = DataLoader(
        dataset,
        batch_size=batch_size,
        shuffle=True,
        num_workers=workers,
        collate_fn=collate,
        persistent_workers=workers > 0,
    )
    iterator = iter(loader)
    next(iterator)  # worker start-up is not throughput
    seen, start = 0, time.perf_counter()
    while seen < records:
        try:
            batch = next(iterator)
        except StopIteration:
            iterator = iter(loader)
            continue
        seen += batch.batch_size[0]
    return seen / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/bench_loading")
    parser.add_argument("--concept", default="object_persistence")
    parser.add_argument("--records", type=int, default=512)
    parser.add_argument("--batch-size", type=int, default=10)
    arguments = parser.parse_args()
    ensure_dataset(
        arguments.root,
        concepts=[arguments.concept],
        train_examples=128,
        val_pairs=64,
        test_pairs=64,
        generalization_pairs=0,
        progress=True,
    )
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    print("| split | records | workers | records/s |")
    print("|---|---|---|---|")
    for split, kind in (("train", "clips"), ("val", "probe pairs")):
        dataset = open_split(arguments.root, arguments.concept, split)
        for workers in (0, 2):
            rate = records_per_second(dataset, workers, arguments.batch_size, arguments.records)
            print(f"| {split} | {kind} | {workers} | {rate:,.0f} |")


if __name__ == "__main__":
    main()
