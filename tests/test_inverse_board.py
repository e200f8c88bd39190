"""The board of ``--beams auto``'s candidates: a later candidate's planar-buckling retry is dropped where an
earlier candidate's first design came close to the surface, whichever process ends first."""
from __future__ import annotations

import json
import os
import threading

import pytest

from xshells.errors import InputError
from xshells.inverse.board import CLOSE, MARK, Board, is_close

FLAT = {"status": "missed", "fit_mean": 0.05, "fit_max": 0.12, "coverage": 0.6, "deployed_rise": 0.0, "time_s": 10.0}
BUCKLED = {"status": "missed", "fit_mean": 0.02, "fit_max": 0.06, "coverage": 0.8, "deployed_rise": 0.2, "time_s": 12.0}
NEAR = {"status": "complete", "fit_mean": 0.004, "fit_max": 0.013, "coverage": 0.97, "deployed_rise": 0.3}
MET = {"status": "complete", "fit_mean": 0.008, "fit_max": 0.019, "coverage": 0.97, "deployed_rise": 0.3}
NO_STAGE = {"status": "stopped", "fit_mean": None, "fit_max": None, "coverage": None, "segments": 40, "time_s": 9.0}


@pytest.mark.parametrize("result, close", [
    (NEAR, True),
    (MET, False),  # within the bar, not within CLOSE's mean: a second design may still do better
    ({**NEAR, "fit_max": 0.021}, False),
    ({**NEAR, "status": "missed"}, False),  # its coverage, or a planar state, missed the bar
    ({"status": "complete", "fit_mean": CLOSE["fit_mean"], "fit_max": CLOSE["fit_max"]}, True),
    ({"status": "complete"}, False),
    (None, False),
])
def test_a_design_is_close_within_the_realizable_bar_only_when_complete(result, close):
    assert is_close(result) == close


def test_a_board_knows_only_once_every_earlier_candidate_has_posted_or_one_is_close(tmp_path):
    a, b, c = (str(tmp_path / n) for n in ("geodesic", "even", "fanned"))
    board = Board(c, [a, b])
    assert board.decided() is None
    Board(b, [a]).post(FLAT)
    assert board.decided() is None  # the first candidate is not known yet
    Board(a, []).post(MET)
    assert board.decided() is False and board.reason() == ""
    os.remove(os.path.join(a, MARK))
    Board(a, []).post(NEAR)
    assert board.decided() is True and "the geodesic net's first design" in board.reason() and "0.40%" in board.reason()
    # one close candidate decides it, whatever the others
    os.remove(os.path.join(b, MARK))
    assert board.decided() is True
    assert Board(a, []).decided() is False  # the first candidate has no earlier one


def test_a_design_within_the_bar_decides_only_for_a_net_that_kept_no_stage(tmp_path):
    a, b = str(tmp_path / "even"), str(tmp_path / "fanned")
    board = Board(b, [a])
    assert board.decided(met=True) is None
    Board(a, []).post({**MET, "status": "missed"})  # within the fit figures, but its coverage missed
    assert board.decided(met=True) is False
    os.remove(os.path.join(a, MARK))
    Board(a, []).post(MET)
    assert board.decided() is False and board.reason() == ""  # a flat net's retry still runs
    assert board.decided(met=True) is True
    assert "the even net's first design meets the bar already (fit mean 0.80%, max 1.90%)" in board.reason(met=True)
    assert "kept no stage" in board.reason(met=True)


def test_a_failed_candidate_counts_as_not_close_and_does_not_overwrite_its_first_design(tmp_path):
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    Board(a, []).post_failed()
    assert json.loads((tmp_path / "a" / MARK).read_text()) == {"close": False}
    assert Board(b, [a]).decided() is False
    Board(b, [a]).post(NEAR)
    Board(b, [a]).post_failed()  # failed after its first design: that design stands
    assert json.loads((tmp_path / "b" / MARK).read_text())["close"] is True


def test_waiting_on_the_board_stops_when_asked(tmp_path):
    board = Board(str(tmp_path / "b"), [str(tmp_path / "a")])
    with pytest.raises(KeyboardInterrupt):
        board.wait(stop=lambda: True, poll=0.01)
    timer = threading.Timer(0.1, lambda: Board(str(tmp_path / "a"), []).post(FLAT))
    timer.start()
    assert board.wait(poll=0.01) is False
    timer.join()


def _fake_designs(results, on_second=None):
    """:func:`test_inverse_run._fake_design` (a stand-in for :func:`_design_with_net`), which here also raises a
    result that is an exception, and runs ``on_second(stop)`` inside the second design (the buckling retry)."""
    from test_inverse_run import _fake_design

    fake, calls = _fake_design(results)

    def wrapped(surface_path, out_dir, material_spec, options, net_path, progress, beams_reason=None, stop=None):
        if isinstance(results[len(calls)], Exception):
            raise results[len(calls)]
        if len(calls) == 1 and on_second is not None:
            calls.append(options.buckling)  # counted as begun, as the real second design would be
            on_second(stop)
            calls.pop()
        return fake(surface_path, out_dir, material_spec, options, net_path, progress, beams_reason, stop)

    return wrapped, calls


def _run_once(tmp_path, monkeypatch, results, board, on_second=None):
    import xshells.inverse.run as run

    fake, calls = _fake_designs(results, on_second)
    monkeypatch.setattr(run, "_design_with_net", fake)
    out = str(tmp_path / "candidates" / "even")
    r = run._run_once("s.obj", out, {}, run.InverseOptions(), None, False, board=board)
    with open(os.path.join(out, "result.json")) as fh:
        assert json.load(fh) == r
    return r, calls, open(os.path.join(out, "flat_design.obj")).read()


def test_no_retry_where_an_earlier_candidate_is_close_already(tmp_path, monkeypatch):
    Board(str(tmp_path / "candidates" / "geodesic"), []).post(NEAR)
    board = Board(str(tmp_path / "candidates" / "even"), [str(tmp_path / "candidates" / "geodesic")])
    r, calls, design = _run_once(tmp_path, monkeypatch, [FLAT, BUCKLED], board)
    assert calls == [None] and design == "design 1\n"
    assert r["status"] == "missed" and r["buckling_retry"]["other"]["status"] == "dropped"
    assert "geodesic" in r["buckling_retry"]["other"]["message"]
    assert json.loads((tmp_path / "candidates" / "even" / MARK).read_text())["close"] is False  # its own, posted


def test_a_retry_is_stopped_once_an_earlier_candidate_comes_close(tmp_path, monkeypatch):
    import xshells.inverse.run as run

    earlier = str(tmp_path / "candidates" / "geodesic")
    board = Board(str(tmp_path / "candidates" / "even"), [earlier])

    def meanwhile(stop):  # the earlier candidate ends close while the retry runs; the retry's next iteration stops
        Board(earlier, []).post(NEAR)
        assert stop()
        raise KeyboardInterrupt

    r, calls, design = _run_once(tmp_path, monkeypatch, [FLAT, BUCKLED], board, meanwhile)
    assert calls == [None, run.RETRY_BUCKLING] and design == "design 1\n"
    assert r["buckling_retry"]["other"]["status"] == "dropped" and r["fit_mean"] == FLAT["fit_mean"]


def test_the_retry_of_a_net_that_kept_no_stage_stops_once_an_earlier_candidate_meets_the_bar(tmp_path, monkeypatch):
    import xshells.inverse.run as run

    earlier = str(tmp_path / "candidates" / "even")
    board = Board(str(tmp_path / "candidates" / "fanned"), [earlier])

    def meanwhile(stop):  # the earlier candidate ends within the bar, not close: enough for a net with no stage
        assert not stop()
        Board(earlier, []).post(MET)
        assert stop()
        raise KeyboardInterrupt

    r, calls, design = _run_once(tmp_path, monkeypatch, [NO_STAGE, BUCKLED], board, meanwhile)
    assert calls == [None, run.RETRY_BUCKLING] and design == "design 1\n"
    assert r["status"] == "stopped" and r["buckling_retry"]["why"] == "no stage's design could be kept"
    assert r["buckling_retry"]["other"]["status"] == "dropped"
    assert "meets the bar already" in r["buckling_retry"]["other"]["message"]


def test_no_retry_for_a_net_that_kept_no_stage_where_an_earlier_candidate_met_the_bar(tmp_path, monkeypatch):
    Board(str(tmp_path / "candidates" / "even"), []).post(MET)
    board = Board(str(tmp_path / "candidates" / "fanned"), [str(tmp_path / "candidates" / "even")])
    r, calls, design = _run_once(tmp_path, monkeypatch, [NO_STAGE, BUCKLED], board)
    assert calls == [None] and design == "design 1\n" and r["buckling_retry"]["other"]["status"] == "dropped"


def test_the_retry_of_a_net_that_kept_no_stage_counts_where_the_earlier_candidate_missed(tmp_path, monkeypatch):
    import xshells.inverse.run as run

    earlier = str(tmp_path / "candidates" / "even")
    board = Board(str(tmp_path / "candidates" / "fanned"), [earlier])
    timer = threading.Timer(0.3, lambda: Board(earlier, []).post(FLAT))  # the boat: its even net missed far
    timer.start()
    try:
        r, calls, design = _run_once(tmp_path, monkeypatch, [NO_STAGE, BUCKLED], board)
    finally:
        timer.join()
    assert calls == [None, run.RETRY_BUCKLING] and design == "design 2\n"
    assert r["fit_mean"] == BUCKLED["fit_mean"] and r["buckling_retry"]["other"]["status"] == "stopped"


def test_a_retry_that_ends_first_waits_for_the_earlier_candidates_and_then_counts(tmp_path, monkeypatch):
    import xshells.inverse.run as run

    earlier = str(tmp_path / "candidates" / "geodesic")
    board = Board(str(tmp_path / "candidates" / "even"), [earlier])
    timer = threading.Timer(0.3, lambda: Board(earlier, []).post(MET))  # ends after the retry: within the bar only
    r, calls, design = None, None, None
    timer.start()
    try:
        r, calls, design = _run_once(tmp_path, monkeypatch, [FLAT, BUCKLED], board)
    finally:
        timer.join()
    assert calls == [None, run.RETRY_BUCKLING] and design == "design 2\n"  # the retry's design, better, kept
    assert r["fit_mean"] == BUCKLED["fit_mean"] and r["buckling_retry"]["other"]["status"] == "missed"


@pytest.mark.parametrize("first, earlier", [
    (FLAT, NEAR),
    (NO_STAGE, MET),  # a net that kept no stage gives way to an earlier design within the bar
])
def test_a_retry_that_ends_first_is_discarded_where_an_earlier_candidate_then_ends_close(tmp_path, monkeypatch, first,
                                                                                          earlier):
    folder = str(tmp_path / "candidates" / "geodesic")
    board = Board(str(tmp_path / "candidates" / "even"), [folder])
    timer = threading.Timer(0.3, lambda: Board(folder, []).post(earlier))
    timer.start()
    try:
        r, calls, design = _run_once(tmp_path, monkeypatch, [first, BUCKLED], board)
    finally:
        timer.join()
    assert design == "design 1\n" and r["buckling_retry"]["other"]["status"] == "dropped"


def test_a_first_design_that_fails_is_posted_as_not_close(tmp_path, monkeypatch):
    board = Board(str(tmp_path / "candidates" / "even"), [])
    with pytest.raises(InputError):
        _run_once(tmp_path, monkeypatch, [InputError("the first layout inverts")], board)
    assert json.loads((tmp_path / "candidates" / "even" / MARK).read_text()) == {"close": False}


@pytest.mark.parametrize("close_one, retried", [("geodesic", False), ("even", True)])
def test_auto_drops_only_a_later_candidates_retry_one_worker_as_two(tmp_path, monkeypatch, close_one, retried):
    """One worker: the candidates in the plan's order (geodesic, then even). The close candidate drops the other's
    retry only where it comes first, as it would with two workers whichever ended first."""
    import xshells.inverse.run as run
    from test_inverse_run import _write_hypar

    calls = []

    def fake(surface_path, out_dir, material_spec, options, net_path, progress, beams_reason=None, stop=None):
        os.makedirs(out_dir, exist_ok=True)
        calls.append((options.beams, options.buckling))
        r = dict(NEAR if options.beams == close_one else BUCKLED if options.buckling else FLAT, beams=options.beams)
        with open(os.path.join(out_dir, "result.json"), "w") as fh:
            json.dump(r, fh)
        return r

    monkeypatch.setattr(run, "_design_with_net", fake)
    monkeypatch.setattr(run, "geodesic_closure", lambda *a, **k: (True, "it closes"))
    monkeypatch.setattr(run, "_screen", lambda *a, **k: ([], None, "no fan"))
    r = run.run_inverse(str(_write_hypar(tmp_path / "h.obj", n=9)), str(tmp_path / "out"), {},
                        run.InverseOptions(workers=1, heavier=False, refine=False), progress=False)
    other = "even" if close_one == "geodesic" else "geodesic"
    assert calls[0][0] == "geodesic"
    assert ((other, run.RETRY_BUCKLING) in calls) == retried
    assert r["beams"] == close_one
    assert not (tmp_path / "out" / MARK).exists()  # the candidates' bookkeeping stays in their folders
    with open(tmp_path / "out" / "candidates" / other / "result.json") as fh:
        kept = json.load(fh)
    assert kept["buckling_retry"]["other"]["status"] == ("missed" if retried else "dropped")
