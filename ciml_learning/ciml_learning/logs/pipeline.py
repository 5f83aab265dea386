"""Bags → filtered logs → contact-invariant targets: the path every verb shares."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ciml_learning.core.extraction import ExtractionResult, extract
from ciml_learning.core.filters import FilteredLog, filter_state_log
from ciml_learning.core.robot import RobotDescription
from ciml_learning.logs.bagio import BagError
from ciml_learning.logs.loginputs import load_log


@dataclass
class Dataset:
    """Filtered logs and their extraction, concatenated over bags (row-aligned)."""

    log: FilteredLog
    targets: ExtractionResult
    bag_index: np.ndarray          # N, which bag each row comes from
    bags: list[str]
    rejected: dict[str, int]
    inputs: list[dict] = field(default_factory=list)
    """Per bag: measured rate [Hz], stamp report, where each role came from, u_observed."""
    warnings: list[str] = field(default_factory=list)
    """What the logs cannot show (e.g. actuation error not observable), each once."""

    @property
    def u_observed(self) -> bool:
        """True when every bag logs a command the actuation error Γ = τ − u can be read from."""
        return all(i.get("u_observed", True) for i in self.inputs)

    @property
    def rate_hz(self) -> float:
        """The logs' measured rate [Hz] (median over bags)."""
        return float(np.median([i["rate_hz"] for i in self.inputs])) if self.inputs else float("nan")

    @property
    def n_valid(self) -> int:
        return int(self.targets.valid.sum())


LOG_COLUMNS = ("t", "q", "v", "a", "tau", "tau_dot", "u", "contacts", "valid", "segment", "effort_valid")
"""The per-sample arrays of a FilteredLog."""


class _LogJoiner:
    """The bags' filtered logs joined into one FilteredLog, segment ids made distinct. Only the
    columns are kept per bag, and each is released once joined: joining needs one column's
    memory on top of the logs, not a second log."""

    def __init__(self) -> None:
        self.columns: dict[str, list[np.ndarray]] = {f: [] for f in LOG_COLUMNS}
        self.counts: dict[str, int] = {}
        self.segment_rates: list[np.ndarray] = []
        self.n_segments = 0
        self.lengths: list[int] = []

    def add(self, log: FilteredLog) -> None:
        for f in LOG_COLUMNS:
            self.columns[f].append(getattr(log, f))
        self.columns["segment"][-1] = log.segment + self.n_segments
        n_seg = int(log.segment.max()) + 1
        self.n_segments += n_seg
        self.segment_rates.append(np.full(n_seg, log.rate_hz, dtype=float))
        for k, c in log.invalid_counts.items():
            self.counts[k] = self.counts.get(k, 0) + c
        self.lengths.append(len(log))

    def bag_index(self) -> np.ndarray:
        """Which bag (its position in the order added) each row comes from."""
        return np.repeat(np.arange(len(self.lengths)), self.lengths)

    def join(self) -> FilteredLog:
        rates = np.concatenate(self.segment_rates)
        columns = {f: np.concatenate(self.columns.pop(f)) for f in LOG_COLUMNS}
        return FilteredLog(**columns, invalid_counts=self.counts, rate_hz=float(np.median(rates)),
                           segment_rate_hz=rates)


BagMap = Callable[[Callable[[Any], Any], Sequence[Any]], list[Any]]
"""How load_dataset maps its per-bag work: map(fn, items) → [fn(item) …] in item order, e.g. on local
processes or a Dask cluster (learning.cluster.bag_mapper); fn is the module-level read_filtered."""


def read_filtered(item: tuple[RobotDescription, str, Any]) -> tuple[dict, list[str], dict[str, int], FilteredLog]:
    """One bag (robot, path, profile) read through the profile and filtered (offline, zero-phase, for
    its measured rate): its inputs entry, warnings, rejected counts and filtered log. Each bag is
    independent of the others: a process pool or a Dask worker can run it."""
    robot, bag, profile = item
    raw = load_log(robot, bag, profile)
    info = {"bag": str(bag), "rate_hz": raw.rate_hz, "u_observed": raw.u_observed, "sources": raw.sources,
            "stamp_report": raw.stamp_report, "torque_command_correlation": raw.torque_command_correlation}
    try:
        log = filter_state_log(raw.t, raw.q, raw.v, raw.tau, raw.u, raw.contacts, fs=raw.rate_hz)
    except ValueError as err:
        raise BagError(f"bag {bag}: {err}") from err
    return info, list(raw.warnings), dict(raw.rejected), log


def load_dataset(robot: RobotDescription, bags: Sequence[str], progress: bool = True, profile=None,
                 map_bags: BagMap | None = None) -> Dataset:
    """Read (through the robot profile; None: CIML's own topics), filter (offline,
    zero-phase, designed for each log's measured rate) and extract every bag; raise if
    nothing is valid. map_bags: how the bags are read and filtered (read_filtered per bag, e.g. on
    several cores or a cluster); None: one after the other, one bag's raw log in memory at a time."""
    joiner, inputs, warnings = _LogJoiner(), [], []
    rejected: dict[str, int] = {}
    items = [(robot, str(b), profile) for b in bags]
    if map_bags is not None and len(items) > 1:
        per_bag = iter(map_bags(read_filtered, items))
    else:
        iterator = items
        if progress and len(bags) > 1:
            from tqdm import tqdm

            iterator = tqdm(items, desc="read+filter", unit="bag", leave=False)
        per_bag = (read_filtered(item) for item in iterator)
    for info, bag_warnings, bag_rejected, filtered in per_bag:
        for k, c in bag_rejected.items():
            rejected[k] = rejected.get(k, 0) + c
        inputs.append(info)
        warnings += [w for w in bag_warnings if w not in warnings]
        joiner.add(filtered)
    log = joiner.join()
    # eq. (11) per sample, in chunks (extraction.EXTRACTION_CHUNK): its per-sample intermediates are
    # freed chunk by chunk. Filtering cannot be streamed this way: the zero-phase filters need whole
    # segments, so each bag is read and filtered whole (one bag's raw log at a time).
    targets = extract(robot, log.q, log.v, log.a, log.tau, log.u, log.contacts, log.t, log.valid, tau_dot=log.tau_dot,
                      effort_valid=log.effort_valid)
    for k, c in log.invalid_counts.items():
        rejected[k] = rejected.get(k, 0) + c
    ds = Dataset(log=log, targets=targets, bag_index=joiner.bag_index(), bags=[str(b) for b in bags],
                 rejected=rejected, inputs=inputs, warnings=warnings)
    if ds.n_valid == 0:
        raise BagError(f"no valid sample left in {list(map(str, bags))} (rejected: {rejected})")
    return ds
