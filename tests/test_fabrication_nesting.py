"""Nesting strips onto bars and sheets: hand-computed first-fit decreasing, no overlaps, utilization from geometry."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xshells.errors import InputError
from xshells.fabrication import nest_bars, nest_sheets
from xshells.fabrication.nesting import parse_sheet


def test_first_fit_decreasing_by_hand():
    n = nest_bars([3, 6, 2, 5, 4], 10, kerf=0)
    # 6 -> bar 1; 5 -> bar 2; 4 -> bar 1 (full); 3 -> bar 2; 2 -> bar 2 (full)
    assert n.stock_count == 2 and n.utilization == pytest.approx(1.0)
    assert {(q.item, q.stock, q.x) for q in n.placements} == {(1, 0, 0), (4, 0, 6), (3, 1, 0), (0, 1, 5), (2, 1, 8)}
    k = nest_bars([3, 6, 2, 5, 4], 10, kerf=1)
    # 6 -> bar 1 [0, 6]; 5 -> bar 2; 4 -> bar 2 [6, 10]; 3 -> bar 1 [7, 10]; 2 -> bar 3
    assert k.stock_count == 3 and k.offcuts == [0.0, 0.0, 8.0]
    assert k.utilization == pytest.approx(20 / 30)


def _bar_checks(n, lengths, L, kerf):
    per = {}
    for q in n.placements:
        assert 0 <= q.x and q.x + lengths[q.item] <= L + 1e-9
        per.setdefault(q.stock, []).append((q.x, q.x + lengths[q.item]))
    for spans in per.values():
        spans.sort()
        for (a0, a1), (b0, b1) in zip(spans, spans[1:]):
            assert b0 >= a1 + kerf - 1e-9  # no overlap, a kerf between pieces
    assert sorted(q.item for q in n.placements) == list(range(len(lengths)))
    assert n.utilization == pytest.approx(sum(lengths) / (L * n.stock_count))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(1, 100), min_size=1, max_size=40), st.floats(0, 5))
def test_bars_never_overlap_and_use_at_most_twice_the_lower_bound(lengths, kerf):
    L = 100.0 + kerf
    n = nest_bars(lengths, L, kerf)
    _bar_checks(n, lengths, L, kerf)
    # no two bars are both at most half full (any-fit), hence at most 2 * ceil(sum / L) bars
    assert n.stock_count <= 2 * math.ceil(sum(lengths) / L) + 1


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(5, 400), st.sampled_from([3.0, 10.0, 12.0])), min_size=1, max_size=40),
       st.floats(0, 4), st.booleans())
def test_sheets_strips_inside_and_apart(items, kerf, portrait):
    lengths = [a for a, _ in items]
    widths = [b for _, b in items]
    sheet = (120.0, 400.0) if portrait else (400.0, 120.0)
    n = nest_sheets(lengths, widths, sheet, kerf)
    long, short = n.stock_size
    assert (long, short) == (400.0, 120.0)
    rects = {}
    for q in n.placements:
        r = (q.x, q.y, q.x + lengths[q.item], q.y + widths[q.item])
        assert r[0] >= 0 and r[1] >= 0 and r[2] <= long + 1e-9 and r[3] <= short + 1e-9
        for o in rects.get(q.stock, []):
            apart = r[2] + kerf <= o[0] + 1e-9 or o[2] + kerf <= r[0] + 1e-9 or r[3] + kerf <= o[1] + 1e-9 or o[3] + kerf <= r[1] + 1e-9
            assert apart, (r, o)
        rects.setdefault(q.stock, []).append(r)
    area = sum(a * b for a, b in items)
    assert n.utilization == pytest.approx(area / (long * short * n.stock_count))
    assert sum(n.offcuts) == pytest.approx(long * short * n.stock_count - area)


def test_bad_stock_is_one_line():
    with pytest.raises(InputError, match=r"shorter than the longest beam, B2 \(120.0 mm\)"):
        nest_bars([50, 120], 100, labels=["A1", "B2"])
    with pytest.raises(InputError, match="does not fit on a sheet"):
        nest_sheets([50, 120], [10, 10], (100, 50), labels=["A1", "B2"])
    with pytest.raises(InputError, match="positive length"):
        nest_bars([1], -3)
    with pytest.raises(InputError, match="--kerf"):
        nest_bars([1], 10, kerf=float("nan"))
    assert parse_sheet("2500x1250") == (2500.0, 1250.0) and parse_sheet("2500×1250") == (2500.0, 1250.0)
    for bad in ("2500", "axb", "0x100", "100x-2"):
        with pytest.raises(InputError, match="--sheet"):
            parse_sheet(bad)


def test_no_stock_lists_one_strip_per_row():
    from xshells.fabrication import no_nesting

    n = no_nesting([5, 7], kerf=2)
    assert [(q.x, q.y) for q in n.placements] == [(0.0, 0.0), (0.0, 7.0)]
    assert n.utilization is None and np.isclose(n.kerf, 2)


def test_a_sheet_too_small_names_the_longest_strip_that_does_not_fit():
    # the first misfit in label order was named (A02, 1999 mm), not the longest (B12, 3138 mm)
    with pytest.raises(InputError, match=r"beam B3 \(300.0 x 10 mm\), the longest, does not fit on a sheet \(nor do 1 more\)"):
        nest_sheets([200, 120, 300], [10, 10, 10], (150, 100), labels=["A1", "B2", "B3"])
