"""Whether an earlier candidate of ``--beams auto`` already came close to the surface: files on disk that
candidates in other processes read.

A candidate whose first design stays in the plane, or keeps no stage, is designed a second time with the
planar-buckling penalty (:func:`.run._run_once`). That second design costs about as much as the first (the
hyperbolic paraboloid, 2026-12-06: the even net's two designs took 117 s and 144 s of a 286 s run, and its
second design, 2.47 %, lost to the geodesic net's first, 0.39 %). Where a candidate before it in the plan's
order has a first design within :data:`CLOSE`, the second design is dropped: stopped if it runs, discarded
if it has ended.

Where the candidate's first design kept no stage at all (every stage's own deployment failed), its second
design is dropped also where an earlier candidate's first design merely meets the bar (status ``complete``):
that design then goes on to the heavier fit weights (:func:`.run._heavier`), which brought Darth Vader's
realizable target from 0.55 % to 0.29 % (2026-12-07), and the second design held the heavier round back
(Darth Vader: the fanned net's second design ran 26 s past the even net's first and kept no stage either).

The decision depends only on the earlier candidates' first designs, never on which process ends first: a
second design that ends before they are known waits for them. So the kept design is the same with one
worker or two. Earlier candidates start first (the workers take the candidates in the plan's order), so a
candidate waits only on candidates that run or have ended.
"""
from __future__ import annotations

import json
import os
import time

#: a first design this close to the surface (relative to the diagonal: mean and largest joint distance; its
#: status "complete", so its coverage is within the bar too) makes the later candidates' second designs not
#: worth their time. It is issue 18's bar for a surface known to be reachable (a design's own deployed shape),
#: half the analytic bar's mean: a candidate that merely meets the analytic bar (the pointy wings' even net,
#: 0.80 %) still leaves room for a second design that does better (their fanned net's, 0.40 %).
CLOSE = {"fit_mean": 0.005, "fit_max": 0.02}
#: the file each candidate writes once its first design has ended (or failed)
MARK = "first.json"


def close_misses(result: dict) -> int:
    """How many of :data:`CLOSE`'s two fit figures (mean and largest joint distance) the design ``result`` misses
    (a figure it lacks counts as missed)."""
    mean, top = result.get("fit_mean"), result.get("fit_max")
    return int(mean is None or mean > CLOSE["fit_mean"]) + int(top is None or top > CLOSE["fit_max"])


def is_close(result: dict | None) -> bool:
    """Whether the design ``result`` (a ``result.json``) met the bar within :data:`CLOSE`."""
    return bool(result) and result.get("status") == "complete" and close_misses(result) == 0


class Board:
    """One candidate's view: its own folder, where it posts its first design, and the earlier candidates'.

    Parameters
    ----------
    own : str
        This candidate's folder (``out_dir/candidates/<beams>``).
    earlier : list of str
        The folders of the candidates before it in the plan's order.
    """

    def __init__(self, own: str, earlier: list):
        self.own, self.earlier = own, list(earlier)

    def post(self, first: dict | None) -> None:
        """Say that this candidate's first design has ended (``first``, its result) or failed (None)."""
        from ..io.export import atomic_write_text

        mark = {"close": is_close(first)}
        if first:
            mark.update({k: first.get(k) for k in ("status", "fit_mean", "fit_max")})
        os.makedirs(self.own, exist_ok=True)
        atomic_write_text(os.path.join(self.own, MARK), json.dumps(mark) + "\n")

    def post_failed(self) -> None:
        """Say that this candidate failed, unless it posted already (its first design ended, then it failed)."""
        if not os.path.exists(os.path.join(self.own, MARK)):
            self.post(None)

    def _marks(self) -> list:
        marks = []
        for folder in self.earlier:
            path = os.path.join(folder, MARK)
            if os.path.exists(path):
                with open(path) as fh:
                    marks.append((os.path.basename(os.path.normpath(folder)), json.load(fh)))
            else:
                marks.append((os.path.basename(os.path.normpath(folder)), None))
        return marks

    def _enough(self, mark: dict | None, met: bool) -> bool:
        return mark is not None and (mark["close"] or (met and mark.get("status") == "complete"))

    def decided(self, met: bool = False) -> bool | None:
        """True where an earlier candidate's first design is close (:func:`is_close`), or with ``met`` meets the
        bar at all (status ``complete``); False where every earlier one has ended and none does; None while
        that is not known yet."""
        marks = self._marks()
        if any(self._enough(m, met) for _, m in marks):
            return True
        return False if all(m is not None for _, m in marks) else None

    def reason(self, met: bool = False) -> str:
        """Which earlier candidate decided it, in words (where :meth:`decided` is True)."""
        for name, m in self._marks():
            if m is not None and m["close"]:
                return (f"the {name} net's first design is within {100 * CLOSE['fit_mean']:g}% / "
                        f"{100 * CLOSE['fit_max']:g}% of the diagonal already (fit mean {100 * m['fit_mean']:.2f}%, "
                        f"max {100 * m['fit_max']:.2f}%)")
        for name, m in self._marks():
            if self._enough(m, met):
                return (f"the {name} net's first design meets the bar already (fit mean {100 * m['fit_mean']:.2f}%, "
                        f"max {100 * m['fit_max']:.2f}%), and this net's first design kept no stage")
        return ""

    def wait(self, stop=None, poll: float = 0.5, met: bool = False) -> bool:
        """:meth:`decided`, once known; ``stop()`` true (the parent asks to stop) raises KeyboardInterrupt."""
        while True:
            d = self.decided(met)
            if d is not None:
                return d
            if stop is not None and stop():
                raise KeyboardInterrupt
            time.sleep(poll)
