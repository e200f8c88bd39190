"""Nesting strips onto stock: bars (one dimension) or sheets (shelves of strips), first-fit decreasing.

Strips are rectangles ``length × width`` (mm), always laid along x. A bar
is a piece of stock of the strip's section, ``stock_length`` long; pieces
follow one another with ``kerf`` between them. A sheet is cut into
shelves: rows of strips along its longer side, ``kerf`` apart in both
directions. Both pack the longest strips first into the first bar, shelf
or sheet with room (first-fit decreasing: within 11/9 of the fewest bars
plus one).

Every :class:`Placement` gives a strip's lower-left corner in its stock's
frame: x along the bar, or along the sheet's longer side, y across it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class Placement:
    """Strip ``item`` on stock ``stock`` with its lower-left corner at (x, y), mm."""

    item: int
    stock: int
    x: float
    y: float


@dataclass(frozen=True)
class Nesting:
    """How the strips sit on stock.

    ``kind`` is ``"none"`` (no stock given: strips listed one per row),
    ``"bars"`` or ``"sheets"``. ``stock_size`` is ``(length,)`` for bars and
    ``(long side, short side)`` for sheets. ``offcuts`` lists what each
    piece of stock leaves: the remaining length of each bar, or the unused
    area of each sheet (mm²). ``utilization`` is the strips' share of the
    stock used: total strip length over bar length × bars, or strip area
    over sheet area × sheets.
    """

    kind: str
    stock_size: tuple
    kerf: float
    placements: list = field(default_factory=list)
    stock_count: int = 0
    offcuts: list = field(default_factory=list)
    utilization: float | None = None

    def summary(self) -> dict:
        out = {"kind": self.kind, "stock_count": self.stock_count, "kerf_mm": self.kerf,
               "utilization": self.utilization, "offcuts": [float(round(o, 3)) for o in self.offcuts]}
        if self.kind == "bars":
            out["stock_length_mm"] = self.stock_size[0]
        elif self.kind == "sheets":
            out["sheet_mm"] = list(self.stock_size)
        return out


def _check_positive(value, what: str) -> float:
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise InputError(f"{what} must be a positive length in mm, got {value!r}")
    return v


def _check_kerf(kerf) -> float:
    k = float(kerf)
    if not (np.isfinite(k) and k >= 0):
        raise InputError(f"--kerf must be a non-negative length in mm, got {kerf!r}")
    return k


def no_nesting(widths, kerf: float = 3.0) -> Nesting:
    """No stock given: one strip per row, in the given order, ``kerf`` apart (for drawing)."""
    k = _check_kerf(kerf)
    w = np.asarray(widths, float)
    y = np.concatenate([[0.0], np.cumsum(w + k)])[:-1]
    return Nesting("none", (), k, [Placement(i, i, 0.0, float(y[i])) for i in range(len(w))], len(w), [], None)


def nest_bars(lengths, stock_length: float, kerf: float = 3.0, labels=None) -> Nesting:
    """First-fit decreasing of pieces of ``lengths`` (mm) into bars of ``stock_length``, ``kerf`` between pieces.

    Parameters
    ----------
    lengths : (n,) array
    stock_length : float
    kerf : float
        Material lost to each cut between two pieces (mm).
    labels : list of str, optional
        Names for messages (default: the indices).
    """
    L = _check_positive(stock_length, "--stock-length")
    k = _check_kerf(kerf)
    if k >= L:  # one piece per bar whatever the lengths: a kerf in other units, not a saw
        raise InputError(f"--kerf {k:g} mm is not less than the stock length {L:g} mm")
    lengths = np.asarray(lengths, float)
    names = labels if labels is not None else [str(i) for i in range(len(lengths))]
    if len(lengths) and lengths.max() > L:
        i = int(lengths.argmax())
        raise InputError(f"--stock-length {L:g} mm is shorter than the longest beam, {names[i]} ({lengths[i]:.1f} mm)")
    order = sorted(range(len(lengths)), key=lambda i: (-lengths[i], i))
    used: list[float] = []  # end of the last piece on each bar
    placements = []
    for i in order:
        for b, u in enumerate(used):
            start = u + k if u > 0 else 0.0
            if start + lengths[i] <= L + 1e-9:
                break
        else:
            used.append(0.0)
            b, start = len(used) - 1, 0.0
        placements.append(Placement(int(i), b, float(start), 0.0))
        used[b] = start + lengths[i]
    placements.sort(key=lambda q: (q.stock, q.x))
    util = float(lengths.sum() / (L * len(used))) if used else None
    return Nesting("bars", (L,), k, placements, len(used), [L - u for u in used], util)


def parse_sheet(text: str) -> tuple[float, float]:
    """``W×H`` or ``WxH`` (mm) → (W, H)."""
    parts = str(text).lower().replace("×", "x").split("x")
    try:
        if len(parts) == 2:
            return _check_positive(parts[0], "--sheet width"), _check_positive(parts[1], "--sheet height")
    except (ValueError, InputError):
        pass
    raise InputError(f"--sheet {text}: use WIDTHxHEIGHT in mm, for example 2500x1250")


def nest_sheets(lengths, widths, sheet, kerf: float = 3.0, labels=None) -> Nesting:
    """First-fit decreasing of strips (``lengths`` × ``widths``, mm) onto shelves of sheets ``sheet`` = (W, H).

    Strips lie along the sheet's longer side. A shelf is a row as high as
    the first (widest, at equal length) strip placed on it; a strip goes on
    the first shelf of its height or higher with room, else on a new shelf
    of the first sheet with room, else on a new sheet.
    """
    W, H = (_check_positive(v, "--sheet") for v in sheet)
    k = _check_kerf(kerf)
    long, short = max(W, H), min(W, H)
    if k >= short:
        raise InputError(f"--kerf {k:g} mm is not less than the sheet's short side {short:g} mm")
    lengths, widths = np.asarray(lengths, float), np.asarray(widths, float)
    names = labels if labels is not None else [str(i) for i in range(len(lengths))]
    misfits = [i for i in range(len(lengths)) if lengths[i] > long + 1e-9 or widths[i] > short + 1e-9]
    if misfits:  # named: the longest of them (the first in label order was named, A02 of 1999 mm beside B12 of 3138)
        i = max(misfits, key=lambda j: (lengths[j], widths[j]))
        others = f" (nor do {len(misfits) - 1} more)" if len(misfits) > 1 else ""
        raise InputError(f"--sheet {W:g}x{H:g}: beam {names[i]} ({lengths[i]:.1f} x {widths[i]:.4g} mm), the longest, "
                         f"does not fit on a sheet{others}")
    order = sorted(range(len(lengths)), key=lambda i: (-lengths[i], -widths[i], i))
    shelves: list[list] = []  # [sheet, y, height, end of the last strip]
    sheet_top: list[float] = []  # top of the last shelf on each sheet
    placements = []
    for i in order:
        li, wi = lengths[i], widths[i]
        for sh in shelves:
            x = sh[3] + k if sh[3] > 0 else 0.0
            if wi <= sh[2] + 1e-9 and x + li <= long + 1e-9:
                break
        else:
            for s, top in enumerate(sheet_top):
                y = top + k if top > 0 else 0.0
                if y + wi <= short + 1e-9:
                    break
            else:
                sheet_top.append(0.0)
                s, y = len(sheet_top) - 1, 0.0
            sh = [s, y, wi, 0.0]
            shelves.append(sh)
            sheet_top[s] = y + wi
            x = 0.0
        placements.append(Placement(int(i), int(sh[0]), float(x), float(sh[1])))
        sh[3] = x + li
    placements.sort(key=lambda q: (q.stock, q.y, q.x))
    n = len(sheet_top)
    area = float((lengths * widths).sum())
    per_sheet = np.zeros(n)
    for q in placements:
        per_sheet[q.stock] += lengths[q.item] * widths[q.item]
    util = area / (long * short * n) if n else None
    return Nesting("sheets", (long, short), k, placements, n, [long * short - a for a in per_sheet.tolist()], util)
