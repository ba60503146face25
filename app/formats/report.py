"""Text, Markdown and PNG renderings of calibration results for the command line and the run
folder."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calib.identify import IdentificationResult
from calib.model import INDEX, SystemModel, group_of, unit_of
from calib.observability import INDEX_NAMES
from calib.validation import ErrorStats, rmse

F64 = NDArray[np.float64]


#: the compliant model's extra units, shown scaled: compliance in urad/m, expansion in ppm/K
_SCALED = {"rad/m": (1e6, "urad/m"), "1/K": (1e6, "ppm/K")}


def _display(name: str, value: float) -> tuple[float, str]:
    """Angles shown in degrees (mdeg for small uncertainties), lengths in mm."""
    unit = unit_of(name)
    if unit in _SCALED:
        scale, shown = _SCALED[unit]
        return value * scale, shown
    return (float(np.degrees(value)), "deg") if unit == "rad" else (value, "mm")


def parameter_rows(model: SystemModel, result: IdentificationResult) -> list[list[str]]:
    nominal = model.nominal_x()
    rows = []
    for name, std in zip(result.active, result.std, strict=True):
        k = INDEX[name]
        nom, unit = _display(name, float(nominal[k]))
        val, _ = _display(name, float(result.x[k]))
        s, _ = _display(name, float(std))
        rows.append(
            [
                group_of(name),
                name,
                unit,
                f"{nom:.5f}",
                f"{val:.5f}",
                f"{val - nom:+.5f}",
                f"{s:.5f}",
            ]
        )
    return rows


PARAM_HEADER = ["group", "parameter", "unit", "nominal", "identified", "change", "std"]


def text_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=False)]
    fmt = "  ".join(f"{{:>{w}}}" for w in widths)
    lines = [fmt.format(*header), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*map(str, r)) for r in rows]
    return "\n".join(lines)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(map(str, r)) + " |" for r in rows]
    return "\n".join(lines)


def parameter_table(model: SystemModel, result: IdentificationResult) -> str:
    return text_table(PARAM_HEADER, parameter_rows(model, result))


STATS_HEADER = ["", "n", "RMSE", "mean", "median", "max", "rms x", "rms y", "rms z"]


def stats_rows(stats: Mapping[str, ErrorStats]) -> list[list[str]]:
    return [
        [
            label,
            str(s.n),
            f"{s.rmse_mm:.4f}",
            f"{s.mean_mm:.4f}",
            f"{s.median_mm:.4f}",
            f"{s.max_mm:.4f}",
            *(f"{v:.4f}" for v in s.axis_rms_mm),
        ]
        for label, s in stats.items()
    ]


def index_rows(indices: Mapping[str, Mapping[str, float]]) -> list[list[str]]:
    return [[label, *(f"{v[n]:.5g}" for n in INDEX_NAMES)] for label, v in indices.items()]


def plot_errors(path: Path, errors_mm: Mapping[str, F64], title: str) -> None:
    """Euclidean validation error per position for each labelled parameter set (like the
    paper's Fig. 11), written as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5), dpi=110)
    for label, e in errors_mm.items():
        d = np.linalg.norm(np.asarray(e).reshape(-1, 3), axis=1)
        ax.plot(
            np.arange(1, d.size + 1),
            d,
            marker="o",
            ms=3,
            lw=1,
            label=f"{label} (RMSE {rmse(e):.3f} mm)",
        )
    ax.set_xlabel("validation position index")
    ax.set_ylabel("Euclidean position error [mm]")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig: Any, path: Path) -> None:
    """Write a matplotlib figure as PNG atomically (app.formats.files.write_bytes) and close it."""
    import io

    import matplotlib.pyplot as plt

    from app.formats.files import write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    write_bytes(path, buf.getvalue())
