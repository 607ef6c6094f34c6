"""Pinned evaluation runs (issue 30): what an evaluation directory was flown with, checked on every resume.

OUT/pin.json records the sha256 of the policy file, of the policy node config the nodes read (the tier's
complete config, written to OUT/policy_config.yaml), of the simulator config and the vehicle file it names,
of the expert's planner config, the tier, the evaluation set, the commit and the CPU (`cpu_signature`: a
closed loop flown on a CPU of another instruction set takes other trajectories, because LibTorch and the
libraries' SIMD paths round differently). `run_eval` resuming into OUT with any of them different (a pin
without the CPU, written before it was recorded, matches any) stops with a message naming each difference
(`--force-new` moves the old run aside and starts over). The policy fields of an expert-only run are empty;
a later run may fill them in as long as no policy episode was flown.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

PIN_FILE = "pin.json"
PIN_FORMAT = 1


@dataclass(frozen=True)
class RunPin:
    """What an evaluation directory was flown with. Hashes are hex sha256; '' = not used by this run."""

    tier: str
    eval_set: str  # '' = seeds and episodes given by hand
    policy_sha256: str
    policy_path: str
    policy_config_sha256: str  # of OUT/policy_config.yaml, the complete config both policy nodes read
    policy_config_base: str  # the config the tier was applied to
    sim_config_sha256: str
    sim_config_path: str
    vehicle_sha256: str
    planner_config_sha256: str  # the expert's (config/planner.yaml)
    density: float | None
    commit: str
    dirty: bool | None
    backend: str = "ros"  # where the episodes were flown (ros | engine; pins written before: ros)
    cpu: str = ""  # cpu_signature() of the machine ('' in pins written before it was recorded: unknown)

    # Fields that must be equal on resume (paths may move; the hashes say whether the content did).
    CHECKED = (
        "tier",
        "eval_set",
        "policy_sha256",
        "policy_config_sha256",
        "sim_config_sha256",
        "vehicle_sha256",
        "planner_config_sha256",
        "density",
        "commit",
        "backend",
        "cpu",
    )
    # What only the policy controllers use: all empty when an invocation flies the expert alone.
    POLICY_FIELDS = ("tier", "policy_sha256", "policy_path", "policy_config_sha256", "policy_config_base")

    def flies_policy(self) -> bool:
        return bool(self.policy_sha256)

    def to_json(self) -> str:
        return json.dumps({"format": PIN_FORMAT, **dataclasses.asdict(self)}, indent=1)

    @classmethod
    def from_json(cls, text: str, source: str) -> RunPin:
        try:
            tree: dict[str, Any] = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"{source}: not valid JSON ({e})") from None
        if tree.pop("format", None) != PIN_FORMAT:
            raise ValueError(f"{source}: not a format-{PIN_FORMAT} evaluation pin")
        names = {f.name for f in dataclasses.fields(cls)}
        tree.setdefault("backend", "ros")  # pins written before the engine existed
        tree.setdefault("cpu", "")  # pins written before the CPU was recorded
        if set(tree) != names:
            raise ValueError(f"{source}: pin keys {sorted(set(tree) ^ names)} missing or unknown")
        return cls(**tree)


def differences(old: RunPin, new: RunPin, policy_flown: bool) -> list[str]:
    """Human-readable differences that forbid resuming `old` with `new` (empty: same run). An invocation that
    flies no policy is not compared on the policy's fields; one that does may fill in a run's empty policy
    fields only while no policy episode was flown."""
    skip: set[str] = set()
    if not new.flies_policy() or (not old.flies_policy() and not policy_flown):
        skip = set(RunPin.POLICY_FIELDS)
    out = []
    for name in RunPin.CHECKED:
        a, b = getattr(old, name), getattr(new, name)
        if name == "cpu" and not (a and b):
            continue  # a pin written before the CPU was recorded: unknown, not different
        if a != b and name not in skip:
            out.append(f"{name}: run has {a!r}, this invocation {b!r}")
    return out


def merge(old: RunPin, new: RunPin) -> RunPin:
    """`new`, keeping the policy fields of `old` when `new` flies no policy."""
    if new.flies_policy():
        return new
    return dataclasses.replace(new, **{name: getattr(old, name) for name in RunPin.POLICY_FIELDS})


VECTOR_FLAGS = ("amx_tile", "avx512f", "avx2", "fma", "sse4_2")


def cpu_signature(cpuinfo: str | None = None) -> str:
    """The CPU's model name and the vector instruction sets that decide how its float kernels round, e.g.
    'Intel(R) Xeon(R) Processor; amx_tile avx512f avx2 fma sse4_2' (from /proc/cpuinfo, or the text given);
    the machine type alone where /proc/cpuinfo cannot be read."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    model, flags = "", set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "model name" and not model:
            model = value.strip()
        elif key == "flags" and not flags:
            flags = set(value.split())
    if not model and not flags:
        import platform

        return platform.machine() or "unknown"
    return f"{model or 'unknown model'}; " + " ".join(f for f in VECTOR_FLAGS if f in flags)


def read_pin(out: Path) -> RunPin | None:
    p = out / PIN_FILE
    if not p.is_file():
        return None
    return RunPin.from_json(p.read_text(), str(p))


def write_pin(out: Path, pin: RunPin) -> None:
    tmp = out / (PIN_FILE + ".tmp")
    tmp.write_text(pin.to_json())
    tmp.replace(out / PIN_FILE)
