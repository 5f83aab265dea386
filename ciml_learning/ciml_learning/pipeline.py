"""Bags → filtered logs → contact-invariant targets: the path every verb shares."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .bagio import BagError
from .extraction import ExtractionResult, extract
from .filters import FilteredLog, filter_state_log
from .loginputs import load_log
from .robot import RobotDescription


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


def _concat_logs(logs: list[FilteredLog]) -> FilteredLog:
    fields = ("t", "q", "v", "a", "tau", "tau_dot", "u", "contacts", "valid")
    counts: dict[str, int] = {}
    for log in logs:
        for k, c in log.invalid_counts.items():
            counts[k] = counts.get(k, 0) + c
    seg, offset, seg_rate = [], 0, []
    for log in logs:
        seg.append(log.segment + offset)
        n_seg = int(log.segment.max()) + 1
        offset += n_seg
        seg_rate.append(np.full(n_seg, log.rate_hz, dtype=float))
    rates = np.concatenate(seg_rate)
    return FilteredLog(**{f: np.concatenate([getattr(log, f) for log in logs]) for f in fields},
                       invalid_counts=counts, segment=np.concatenate(seg), rate_hz=float(np.median(rates)),
                       segment_rate_hz=rates)


def load_dataset(robot: RobotDescription, bags: Sequence[str], progress: bool = True, profile=None) -> Dataset:
    """Read (through the robot profile; None: CIML's own topics), filter (offline,
    zero-phase, designed for each log's measured rate) and extract every bag; raise if
    nothing is valid."""
    logs, index, inputs, warnings = [], [], [], []
    rejected: dict[str, int] = {}
    iterator = bags
    if progress and len(bags) > 1:
        from tqdm import tqdm

        iterator = tqdm(bags, desc="read+filter", unit="bag", leave=False)
    for i, bag in enumerate(iterator):
        raw = load_log(robot, bag, profile)
        for k, c in raw.rejected.items():
            rejected[k] = rejected.get(k, 0) + c
        inputs.append({"bag": str(bag), "rate_hz": raw.rate_hz, "u_observed": raw.u_observed,
                       "sources": raw.sources, "stamp_report": raw.stamp_report,
                       "torque_command_correlation": raw.torque_command_correlation})
        warnings += [w for w in raw.warnings if w not in warnings]
        try:
            log = filter_state_log(raw.t, raw.q, raw.v, raw.tau, raw.u, raw.contacts, fs=raw.rate_hz)
        except ValueError as err:
            raise BagError(f"bag {bag}: {err}") from err
        logs.append(log)
        index.append(np.full(len(log), i))
    log = _concat_logs(logs)
    targets = extract(robot, log.q, log.v, log.a, log.tau, log.u, log.contacts, log.t, log.valid, tau_dot=log.tau_dot)
    for k, c in log.invalid_counts.items():
        rejected[k] = rejected.get(k, 0) + c
    ds = Dataset(log=log, targets=targets, bag_index=np.concatenate(index), bags=[str(b) for b in bags],
                 rejected=rejected, inputs=inputs, warnings=warnings)
    if ds.n_valid == 0:
        raise BagError(f"no valid sample left in {list(map(str, bags))} (rejected: {rejected})")
    return ds
