"""The sweep's table (``results.csv``), a text summary and plots.

Plots depend only on column names, so any task gets them when its results
have the columns: a contact sheet of ``deployed.png`` and energy against
angle (``energy``, ``average_angle_deg``), and the Fig. 9 trade-off
(``num_actuators``, ``fit_mean``, ``p``).
"""
from __future__ import annotations

import csv
import io
import math
import os

from ..io.export import atomic_write_text
from .spec import SweepSpec

LEADING = ("index", "id", "status")
TRAILING = ("elapsed_s", "cpu_s", "peak_rss_mb", "error")


def _cell(v):
    if isinstance(v, (list, tuple)):
        return " ".join(_cell(x) for x in v)
    if isinstance(v, float):
        return repr(v)  # round-trips: the CSV holds the exact numbers
    return "" if v is None else str(v)


def table(spec: SweepSpec, records: dict) -> tuple[list, list]:
    """(columns, rows) of the finished tasks in sweep order; rows are dicts of raw values."""
    rows, result_keys = [], []
    for task in spec.tasks:
        rec = records.get(task.id)
        if rec is None:
            continue
        for k in rec["result"]:
            if k not in result_keys:
                result_keys.append(k)
        row = {"index": task.index, "id": task.id, "status": rec["status"], **task.varying, **rec["result"],
               "elapsed_s": rec["elapsed_s"], "cpu_s": rec.get("cpu_s"), "peak_rss_mb": rec.get("peak_rss_mb"),
               "error": rec["error"]}
        rows.append(row)
    columns = list(LEADING) + [k for k in spec.varying_keys if k not in LEADING]
    columns += [k for k in result_keys if k not in columns and k not in TRAILING] + list(TRAILING)
    return columns, rows


def write_results_csv(out_dir: str, spec: SweepSpec, records: dict) -> str:
    """Rewrite ``out_dir/results.csv`` atomically; returns its path."""
    columns, rows = table(spec, records)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in columns])
    path = os.path.join(out_dir, "results.csv")
    atomic_write_text(path, buf.getvalue())
    return path


def format_table(spec: SweepSpec, records: dict, *, max_rows: int = 40) -> str:
    """A short text table for the terminal: status, varying keys and a few results."""
    columns, rows = table(spec, records)
    preferred = ("energy", "average_angle_deg", "max_abs_z", "J", "energy_deployed", "num_actuators", "fit_mean")
    shown = ["id", "status"] + list(spec.varying_keys) + [c for c in preferred if c in columns] + ["elapsed_s", "error"]

    def fmt(v):
        if isinstance(v, float):
            return f"{v:.5g}"
        s = _cell(v)
        return s if len(s) <= 48 else s[:45] + "..."

    body = [[fmt(r.get(c)) for c in shown] for r in rows[:max_rows]]
    widths = [max([len(c)] + [len(b[i]) for b in body]) for i, c in enumerate(shown)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(shown, widths))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(b, widths)) for b in body]
    if len(rows) > max_rows:
        lines.append(f"... {len(rows) - max_rows} more rows in results.csv")
    return "\n".join(lines)


def _label(varying: dict) -> str:
    parts = []
    for k, v in varying.items():
        if isinstance(v, str):
            v = os.path.basename(v)
        elif isinstance(v, float):
            v = f"{v:g}"
        elif isinstance(v, list):
            v = "×".join(f"{x:g}" if isinstance(x, float) else str(x) for x in v)
        parts.append(f"{k.split('.')[-1]}={v}")
    return "\n".join(", ".join(parts[i:i + 2]) for i in range(0, len(parts), 2))  # two per line: tiles are narrow


def contact_sheet(path: str, out_dir: str, spec: SweepSpec, records: dict,
                  images: tuple = ("deployed.png", "actuators.png"), max_tiles: int = 48) -> bool:
    """A grid of the finished tasks' pictures titled by their varying parameters (as Fig. 14); False if none.

    Each task shows the first of ``images`` in its folder (deploy and
    optimize write ``deployed.png``, sparsify ``actuators.png``). Only the
    first ``max_tiles`` are drawn: a sheet of thousands is unreadable (see results.csv).
    """
    from ..viz.render import _pyplot, _save

    tiles = []
    for t in spec.tasks:
        if records.get(t.id) and records[t.id]["status"] != "failed":
            found = [p for p in (os.path.join(out_dir, "tasks", t.id, im) for im in images) if os.path.isfile(p)]
            if found:
                tiles.append((t, found[0]))
    tiles = tiles[:max_tiles]
    if not tiles:
        return False
    plt = _pyplot()
    cols = min(4, len(tiles))
    rows = math.ceil(len(tiles) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.0 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (task, p) in zip(axes.ravel(), tiles):
        ax.imshow(plt.imread(p))
        status = records[task.id]["status"]
        ax.set_title(_label(task.varying) + ("" if status == "ok" else f" [{status}]"), fontsize=7)
    fig.suptitle(spec.name)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def energy_angle_plot(path: str, spec: SweepSpec, rows: list) -> bool:
    """Deployed energy against average angle, one colour per design file; False without the columns."""
    from ..viz.render import _pyplot, _save

    pts = [r for r in rows if r["status"] != "failed" and _finite(r.get("energy")) and _finite(r.get("average_angle_deg"))]
    if not pts:
        return False
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    group = "file" if "file" in spec.varying_keys else None
    for g in sorted({str(r.get(group, "")) for r in pts}):
        sel = [r for r in pts if str(r.get(group, "")) == g]
        ax.scatter([r["average_angle_deg"] for r in sel], [r["energy"] for r in sel], s=18,
                   label=os.path.basename(g) or None)
    if group:
        ax.legend(fontsize=7)
    ax.set_xlabel("average opening angle (°)")
    ax.set_ylabel("elastic energy (input units)")
    ax.set_title(spec.name)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def tradeoff_plot(path: str, spec: SweepSpec, rows: list) -> bool:
    """Fit distance against number of actuators, one curve per p (Fig. 9); False without the columns."""
    from ..viz.render import plot_actuation_tradeoff

    pts = [r for r in rows if r["status"] != "failed" and all(_finite(r.get(k)) for k in ("num_actuators", "fit_mean"))
           and (_finite(r.get("p")) or r.get("method") == "elimination")]
    if not pts:
        return False
    plot_actuation_tradeoff(path, pts, title=spec.name)
    return True


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def write_summary(out_dir: str, spec: SweepSpec, records: dict) -> list:
    """Write the plots that the results' columns allow; returns the paths written."""
    _, rows = table(spec, records)
    for r in rows:  # task parameters (p, eta, ...) live in the record's params when not varied
        params = records[r["id"]]["params"]
        for k, v in params.items():
            r.setdefault(k, v)
    written = []
    plots = [("contact_sheet.png", lambda p: contact_sheet(p, out_dir, spec, records)),
             ("energy_vs_angle.png", lambda p: energy_angle_plot(p, spec, rows)),
             ("tradeoff.png", lambda p: tradeoff_plot(p, spec, rows))]
    for name, draw in plots:
        path = os.path.join(out_dir, name)
        if draw(path):
            written.append(path)
    return written
