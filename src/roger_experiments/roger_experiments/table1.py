"""``roger table1``: the paper's Table 1 as Roger perceives worlds/table1.yaml.

Four boxes of equal size whose intensities (99/79/69/59) and weights (15/10/10/5) differ.
The robot looks at them as in ``roger features`` (initial scan, then a shift, a visual and a
haptic improvement and a shift back on every place it settled); for each box, the
perceived I, D and W are the means over its looks at the focus (W from the looks after the
haptic improvement), next to the paper's perceived values. Which place is which box comes
from the simulator's labels (scoring only).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from roger_common.atomic import atomic_write_bytes
from roger_common.types import FEATURE_NAMES, SIZE_INDEX, WEIGHT_INDEX, WorldSpec
from roger_experiments.feature_report import PURE_SHARE, LookLog, collect_looks

#: Table 1 of the paper: (world intensity, size cm, weight units; perceived I, D, W).
PAPER_TABLE1: dict[str, tuple[float, float, float, float, float, float]] = {
    "obj01": (99, 30, 15, 0.83, 0.45, 0.72),
    "obj02": (79, 30, 10, 0.65, 0.43, 0.51),
    "obj03": (69, 30, 10, 0.56, 0.44, 0.47),
    "obj04": (59, 30, 5, 0.47, 0.44, 0.24),
}
_I = [FEATURE_NAMES.index(f"I{k}") for k in (1, 2, 3)]
_D, _W = SIZE_INDEX, WEIGHT_INDEX


def table1(log: LookLog) -> dict[str, Any]:
    """Per box: the world's values and the perceived I (mean of I^(1..3)), D and W."""
    rows = []
    for obj in log.world.objects:
        looks = [lk for lk in log.looks if lk.focus and lk.obj == obj.name
                 and lk.purity >= PURE_SHARE]
        # A feature counts only from the looks that measured it (a look cut by the
        # retina's edge has no I or D; W is known after the haptic improvement).
        lit = np.stack([lk.roi.features[_I] for lk in looks if lk.roi.known[_I].all()]
                       or [np.full(3, math.nan)])
        sized = [lk.roi.features[_D] for lk in looks if lk.roi.known[_D]]
        weighed = [lk.roi.features[_W] for lk in looks if lk.roi.known[_W]]
        paper = PAPER_TABLE1.get(obj.name)
        rows.append({
            "object": obj.name, "intensity": obj.intensity, "size_m": obj.size,
            "weight_kg": obj.weight, "looks": len(looks),
            "I": float(lit.mean()),
            "I_k": [float(v) for v in lit.mean(axis=0)] if np.isfinite(lit).all() else [],
            "I_sd": float(lit.mean(axis=1).std()),
            "D": float(np.mean(sized)) if sized else math.nan,
            "D_sd": float(np.std(sized)) if sized else math.nan,
            "W": float(np.mean(weighed)) if weighed else math.nan,
            "paper": None if paper is None else
            {"intensity": paper[0], "size_cm": paper[1], "weight": paper[2],
             "I": paper[3], "D": paper[4], "W": paper[5]},
        })
    return {"world": log.world.source, "rows": rows}


def markdown(result: dict[str, Any]) -> str:
    """Table 1's layout: world values (odd rows) and perceived features (even rows)."""
    lines = [f"Table 1 on `{result['world']}`: world values, then the features Roger "
             "perceives (mean over its looks at the focus, sd in brackets) and the paper's.",
             "", "| object | intensity | size | weight |", "|---|---|---|---|"]
    for r in result["rows"]:
        p = r["paper"]
        lines.append(f"| {r['object']} | {r['intensity']:g} | {100 * r['size_m']:g} cm | "
                     f"{r['weight_kg']:g} kg |")
        lines.append(f"| here ({r['looks']} looks) | {r['I']:.2f} ({r['I_sd']:.2f}) | "
                     f"{r['D']:.2f} ({r['D_sd']:.2f}) | {r['W']:.2f} |")
        if p is not None:
            lines.append(f"| paper | {p['I']:.2f} | {p['D']:.2f} | {p['W']:.2f} |")
    lines += ["", "I is the mean of I^(1), I^(2), I^(3) (equation 1); D is equation 4, W "
              "equation 5 (known after the haptic improvement).", ""]
    return "\n".join(lines)


def write(world: WorldSpec, out: Path, seed: int = 0) -> dict[str, Any]:
    """Look at the world, write table1.md and table1.json to ``out``; return the result."""
    out.mkdir(parents=True, exist_ok=True)
    result = table1(collect_looks(world, seed=seed))
    atomic_write_bytes(out / "table1.json", (json.dumps(result, indent=2) + "\n").encode())
    atomic_write_bytes(out / "table1.md", markdown(result).encode())
    return result
