"""Bags → filtered logs → contact-invariant targets: the path every verb shares."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .bagio import BagError, load_sensor_log
from .extraction import ExtractionResult, extract
from .filters import FilteredLog, filter_state_log
from .robot import RobotDescription


@dataclass
class Dataset:
    """Filtered logs and their extraction, concatenated over bags (row-aligned)."""

    log: FilteredLog
    targets: ExtractionResult
    bag_index: np.ndarray          # N, which bag each row comes from
    bags: list[str]
    rejected: dict[str, int]

    @property
    def n_valid(self) -> int:
        return int(self.targets.valid.sum())


def _concat_logs(logs: list[FilteredLog]) -> FilteredLog:
    fields = ("t", "q", "v", "a", "tau", "tau_dot", "u", "contacts", "valid")
    counts: dict[str, int] = {}
    for log in logs:
        for k, c in log.invalid_counts.items():
            counts[k] = counts.get(k, 0) + c
    seg, offset = [], 0
    for log in logs:
        seg.append(log.segment + offset)
        offset += int(log.segment.max()) + 1
    return FilteredLog(**{f: np.concatenate([getattr(log, f) for log in logs]) for f in fields},
                       invalid_counts=counts, segment=np.concatenate(seg))


def load_dataset(robot: RobotDescription, bags: Sequence[str], progress: bool = True) -> Dataset:
    """Read, filter (offline, zero-phase) and extract every bag; raise if nothing is valid."""
    logs, index, rejected = [], [], {}
    iterator = bags
    if progress and len(bags) > 1:
        from tqdm import tqdm

        iterator = tqdm(bags, desc="read+filter", unit="bag", leave=False)
    for i, bag in enumerate(iterator):
        raw = load_sensor_log(robot, bag)
        for k, c in raw.rejected.items():
            rejected[k] = rejected.get(k, 0) + c
        try:
            log = filter_state_log(raw.t, raw.q, raw.v, raw.tau, raw.u, raw.contacts)
        except ValueError as err:
            raise BagError(f"bag {bag}: {err}") from err
        logs.append(log)
        index.append(np.full(len(log), i))
    log = _concat_logs(logs)
    targets = extract(robot, log.q, log.v, log.a, log.tau, log.u, log.contacts, log.t, log.valid, tau_dot=log.tau_dot)
    for k, c in log.invalid_counts.items():
        rejected[k] = rejected.get(k, 0) + c
    ds = Dataset(log=log, targets=targets, bag_index=np.concatenate(index), bags=[str(b) for b in bags],
                 rejected=rejected)
    if ds.n_valid == 0:
        raise BagError(f"no valid sample left in {list(map(str, bags))} (rejected: {rejected})")
    return ds
