"""Band analysis of the microgravity assessment against closed forms (issue #13 item 2)."""
import numpy as np
import pytest

import spidersim

from spidersim import microgravity as mg
from spidersim.sampling import NonUniformRecord


def test_bands_are_contiguous_third_octaves():
    b = mg.third_octave_bands(0.01, 300)
    np.testing.assert_allclose(b[1:, 0], b[:-1, 2], rtol=1e-12)       # no gaps, no overlap
    np.testing.assert_allclose(b[:, 2] / b[:, 0], 10 ** 0.1, rtol=1e-12)
    np.testing.assert_allclose(b[b[:, 1] > 99, 1][0], 100.0)            # base-10 centres
    assert b[0, 1] == pytest.approx(0.01) and b[-1, 1] == pytest.approx(10 ** 2.4)


def test_iss_limit_curve():
    np.testing.assert_allclose(mg.iss_limit([0.01, 0.05, 0.1, 1.0, 10.0, 100.0, 200.0]),
                               [1.6, 1.6, 1.6, 16.0, 160.0, 1600.0, 1600.0])
    assert np.isnan(mg.iss_limit(500.0)) and np.isnan(mg.iss_limit(0.001))


@pytest.mark.parametrize("f0,amp,periodic", [(5.0, 3.0, True), (5.37, 3.0, False),
                                             (0.8, 0.2, False), (63.0, 10.0, True)])
def test_band_rms_of_a_sine(f0, amp, periodic):
    """A sine of amplitude A gives A / sqrt(2) in its band (within 1 %); under 2 % of its
    power leaks into other bands (rectangular window, record not a whole number of periods)."""
    dt, T = 1e-3, 20.0 if periodic else 20.123
    t = np.arange(0, T, dt)
    x = 7.0 + amp * np.sin(2 * np.pi * f0 * t + 0.3)                   # a mean to remove
    bands = mg.third_octave_bands(0.1, 300)
    lev = mg.band_rms(x, dt, bands)
    k = int(np.argmax((bands[:, 0] <= f0) & (f0 < bands[:, 2])))
    assert lev[k] == pytest.approx(amp / np.sqrt(2), rel=0.01)
    others = np.delete(lev, k)
    assert np.nansum(others ** 2) < 0.02 * amp ** 2 / 2      # < 2 % of the power leaks


def test_wrong_band_edges_would_be_caught():
    """Octave-wide bands put a neighbouring tone into the same band: the check above fails."""
    dt = 1e-3
    t = np.arange(0, 20, dt)
    x = np.sin(2 * np.pi * 5 * t) + np.sin(2 * np.pi * 7 * t)          # 5 and 7 Hz
    third = mg.band_rms(x, dt, mg.third_octave_bands(4, 8))
    octave = mg.band_rms(x, dt, np.array([[5 / 2 ** 0.5, 5.0, 5 * 2 ** 0.5]]))
    assert np.nanmax(third) == pytest.approx(1 / np.sqrt(2), rel=0.01)
    assert octave[0] == pytest.approx(1.0, rel=0.01)                   # both tones


def test_assess_force_to_acceleration_and_verdict():
    """F / M in micro-g; a 1 N, 10 Hz force on 4.2e5 kg: 0.24 micro-g peak, 0.17 RMS."""
    dt = 1e-3
    t = np.arange(0, 20 + dt / 2, dt)
    F = np.column_stack([np.sin(2 * np.pi * 10 * t), 0 * t, 0 * t])
    a = mg.assess(t, F, 4.2e5, window=(4, 20))
    ug = 1 / 4.2e5 / mg.MICRO_G
    k = int(np.argmin(abs(a.bands[:, 1] - 10)))
    assert a.worst[k] == pytest.approx(ug / np.sqrt(2), rel=0.01)
    assert a.peak == pytest.approx(ug, rel=1e-3)
    assert a.passed and a.margin_db[k] == pytest.approx(
        20 * np.log10(160 / (ug / np.sqrt(2))), abs=0.1)
    # the same force on a 100 kg "station" exceeds the limit
    assert not mg.assess(t, F, 100.0, window=(4, 20)).passed
    assert "EXCEEDS" in mg.assess(t, F, 100.0, window=(4, 20)).table()


def test_non_uniform_record_is_resampled_on_request():
    """``resample=True`` interpolates a dense, jittered record (2 Hz sine, 2000 points a
    second): its band level within 2 % of A / sqrt(2)."""
    rng = np.random.default_rng(1)
    t = np.sort(np.concatenate([[0, 20], rng.uniform(0, 20, 40000)]))
    F = np.sin(2 * np.pi * 2 * t)
    a = mg.assess(t, F, 1.0, resample=True)                             # M = 1 kg
    k = int(np.argmin(abs(a.bands[:, 1] - 2)))
    assert a.worst[k] == pytest.approx(1 / mg.MICRO_G / np.sqrt(2), rel=0.02)


def test_window_outside_record_is_refused():
    with pytest.raises(ValueError, match="window"):
        mg.assess(np.linspace(0, 1, 100), np.zeros(100), 1.0, window=(0.5, 2))


def _solver_steps_record():
    """A base force of 5 and 20 Hz tones (50 and 200 N) recorded where the solver stepped
    on mg1_nouniform.yaml of the independent check (sources only, no output_interval):
    steps of 1 us growing tenfold to 0.1 s, then 0.2 s to the end at 10 s."""
    t = np.concatenate([np.cumsum([0.0, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1]),
                        0.111111 + 0.2 * np.arange(1, 50), [10.0]])
    F = 30 + 50 * np.sin(2 * np.pi * 5 * t) + 200 * np.sin(2 * np.pi * 20 * t)
    return t, F


def test_solver_steps_record_is_refused():
    """A record of the solver's own steps is refused, naming output_interval; over the
    window 1..9 s its rows are 0.2 s apart: a grid whose Nyquist frequency (2.5 Hz) leaves
    out every band above 2.5 Hz is refused too. (Interpolated, the 0.2 s rows sampled the 5
    and 20 Hz tones at their zeros: ~1e-13 micro-g in three bands, a PASS with 290 dB of
    margin; f_max under 2.5 Hz shows that aliasing.)"""
    t, F = _solver_steps_record()
    with pytest.raises(NonUniformRecord, match="output_interval"):
        mg.assess(t, F, 4.2e5)
    with pytest.raises(ValueError, match="resolve bands up to 2.5 Hz"):
        mg.assess(t, F, 4.2e5, window=(1, 9))
    aliased = mg.assess(t, F, 4.2e5, window=(1, 9), f_range=(0.01, 2.2))
    assert np.nanmax(aliased.worst) < 1e-6          # what the refusal guards against


def test_record_ending_between_grid_points():
    """A uniform record whose last row is off the grid (a run stopped between two grid
    points) is used without that row: the same levels as the record without it."""
    dt = 1e-3
    t = np.arange(0, 10 + dt / 2, dt)
    F = np.sin(2 * np.pi * 10 * t)
    ref = mg.assess(t, F, 1.0)
    t2, F2 = np.append(t, 10.0004), np.append(F, 0.0)
    a = mg.assess(t2, F2, 1.0, window=(0, 10.0004))
    np.testing.assert_allclose(a.worst, ref.worst, rtol=1e-12)


@pytest.mark.parametrize("f_range, word", [((310.0, 450.0), "f_min"),
                                           ((0.01, 450.0), "f_max"),
                                           ((0.005, 10.0), "f_min"),
                                           ((290.0, 300.0), "no one-third-octave band")])
def test_bands_off_the_limit_curve_are_refused(f_range, word):
    """Band centres outside the limit curve's 0.01..300 Hz (or none in the range) are an
    error, not NaN limits, EXCEEDS rows and a PASS (mg1_hi.yaml, mg1_fmax.yaml)."""
    t = np.arange(0, 10, 1e-3)
    with pytest.raises(ValueError, match=word):
        mg.assess(t, np.sin(2 * np.pi * 400 * t), 1.0, f_range=f_range)
    assert mg.band_range_problem(*f_range)[1] == ("f_min" if "band" in word else word)


def test_no_band_is_no_pass():
    """An assessment without a band (or with a band without a limit) does not PASS."""
    empty = mg.Assessment(np.zeros((0, 3)), np.zeros((0, 1)), np.zeros(0), 0.0, 0.0, (0, 1))
    assert not empty.passed
    nolimit = mg.Assessment(np.array([[355.0, 398.0, 447.0]]), np.array([[1.0]]),
                            mg.iss_limit([398.0]), 1.0, 0.0, (0, 1))
    assert not nolimit.passed


def test_top_band_edge():
    """The top band of f_max = 300 Hz is the 251 Hz band (10^2.4), reaching 10^2.45 Hz."""
    assert mg.top_band_edge(300.0) == pytest.approx(10 ** 2.45, rel=1e-12)
    assert mg.top_band_edge(100.0) == pytest.approx(100 * 10 ** 0.05, rel=1e-12)


MG_DIAGRAM = """\
name: mgcli
blocks:
  s1: {type: Sine, amplitude: 50, f: 5.0, offset: 30}
  s2: {type: Sine, amplitude: 200, f: 20.0}
  zero: {type: Constant, value: 0.0}
  add: {type: Sum, signs: "++"}
  mux: {type: Mux, n: 3}
  integ: {type: Integrator}
connections:
  - s1.y -> add.u1
  - s2.y -> add.u2
  - add.y -> mux.u1
  - zero.y -> mux.u2, mux.u3, integ.u
simulation: {t_end: 10, method: DP54, rtol: 1e-8, atol: 1e-10, output_interval: 1e-3}
log: [mux.y]
microgravity:
  signal: mux.y
  mass: 4.2e5
  window: [1, 9]
"""


def _strict_json(path):
    """The file parsed as strict JSON (NaN, Infinity refused)."""
    import json

    def refuse(name):
        raise ValueError(f"{path}: {name} is not JSON")
    with open(path, encoding="utf-8") as fh:
        return json.load(fh, parse_constant=refuse)


def test_cli_run_levels_verdict_and_strict_json(tmp_path, capsys):
    """``spidersim run`` with a microgravity section: the 5 and 20 Hz bands hold the tones'
    RMS 50 / sqrt(2) / M / micro-g = 8.585 and 34.34 micro-g (1 %), margins
    20 log10(80.2 / 8.585) and 20 log10(319 / 34.34) dB, PASS; microgravity.json and
    report.json are strict JSON."""
    from spidersim.cli import main
    f = tmp_path / "mg.yaml"
    f.write_text(MG_DIAGRAM)
    out = tmp_path / "out"
    assert main(["run", str(f), "--out", str(out), "--no-plots", "--no-jit"]) == 0
    assert "verdict: PASS" in capsys.readouterr().out
    js = _strict_json(out / "microgravity.json")
    _strict_json(out / "report.json")
    bands = {round(b["center_hz"], 1): b for b in js["bands"]}
    ug = 1 / 4.2e5 / mg.MICRO_G
    for fc, amp in ((5.0, 50.0), (20.0, 200.0)):
        b = bands[fc]
        assert b["level_ug"] == pytest.approx(amp * ug / np.sqrt(2), rel=0.01)
        assert b["margin_db"] == pytest.approx(
            20 * np.log10(16 * b["center_hz"] / (amp * ug / np.sqrt(2))), abs=0.1)
    assert js["passed"] is True
    tf = np.arange(0, 0.2, 1e-6)                           # one common period, finely
    peak = np.max(30 + 50 * np.sin(2 * np.pi * 5 * tf) + 200 * np.sin(2 * np.pi * 20 * tf))
    assert js["peak_ug"] == pytest.approx(peak * ug, rel=3e-3)  # 1 ms samples: 0.15 % low


@pytest.mark.parametrize("edit, line, words", [
    ("  window: [1, 9]\n", 20, ["f_max (450 hz) is outside the iss limit curve"]),
    ("  f_min: 310\n", 20, ["f_min (310 hz) is outside"]),
    ("output_interval: 1e-3", 14, ["output_interval (0.002 s) is too long",
                                   "281.8 hz"]),
    ("rtol", 16, ["add simulation.output_interval", "at most 0.001774 s"]),
])
def test_check_refuses_what_gives_no_honest_verdict(tmp_path, capsys, edit, line, words):
    """``spidersim check`` (the validation ``run`` shares) refuses, at the file's line,
    bands beyond the limit curve, and band levels from a record that is not on a grid fine
    enough for the top band (Nyquist of output_interval above its upper edge)."""
    from spidersim.cli import main
    text = MG_DIAGRAM
    if edit.startswith("  window"):
        text = text + "  f_max: 450\n"
    elif edit.startswith("  f_min"):
        text = text + "  f_min: 310\n  f_max: 450\n"
    elif edit.startswith("output_interval"):
        text = text.replace("output_interval: 1e-3", "output_interval: 2e-3")
    else:
        text = text.replace(", output_interval: 1e-3", "")
    f = tmp_path / "mg.yaml"
    f.write_text(text)
    assert main(["check", str(f)]) == 2
    err = capsys.readouterr().err.lower()
    assert f"mg.yaml:{line}:" in err
    for w in words:
        assert w in err


def test_as_dict_is_strict_json():
    """A value that is not a finite number (a band without a limit, here built by hand: the
    checks keep such bands out) is written as null, never as a bare NaN that strict JSON
    readers refuse."""
    import json
    a = mg.Assessment(np.array([[355.0, 398.0, 447.0]]), np.array([[1.0]]),
                      mg.iss_limit([398.0]), 1.0, 0.0, (0, 1))
    d = json.loads(json.dumps(a.as_dict(), allow_nan=False))
    assert d["bands"][0]["limit_ug"] is None and d["bands"][0]["margin_db"] is None
    assert d["passed"] is False


@pytest.mark.parametrize("t1, ok", [(1.0859, False), (1.086, True)])
def test_window_too_short_for_any_band_is_refused_by_check(tmp_path, capsys, t1, ok):
    """f_max 100 Hz: the widest band (89.1-112.2 Hz) needs two bins, n dt >= 2 / 23.1 Hz,
    i.e. 87 samples of 1 ms: a window of 0.086 s. A shorter one resolved no band, so run
    gave no verdict and exit status 0; now check refuses it at the section's line, and the
    shortest accepted window gives a verdict."""
    from spidersim.cli import main
    text = MG_DIAGRAM.replace("  window: [1, 9]\n", f"  window: [1, {t1}]\n  f_max: 100\n")
    f = tmp_path / "mg.yaml"
    f.write_text(text)
    if not ok:
        assert main(["check", str(f)]) == 2
        err = capsys.readouterr().err
        assert "mg.yaml:16:" in err and "needs at least 0.086 s" in err
        return
    out = tmp_path / "out"
    assert main(["run", str(f), "--out", str(out), "--no-plots", "--no-jit",
                 "--t-end", "1.2"]) == 0
    assert "verdict:" in capsys.readouterr().out
    assert len(_strict_json(out / "microgravity.json")["bands"]) == 1


UNIT_DIAGRAM = """\
name: mgunit
blocks:
  s: {{type: Sine, f: 5.0, amplitude: {amplitude}}}
simulation: {{t_end: 4, method: DP54, output_interval: 1e-3}}
microgravity: {{signal: s.y, mass: 4.2e5, f_min: 2, f_max: 20}}
"""


@pytest.mark.parametrize("amplitude", ["50", "{value: 50, unit: N}",
                                       "{value: 0.05, unit: kN}"])
def test_force_in_another_unit_is_converted_to_newtons(tmp_path, capsys, amplitude):
    """A 0.05 kN sine is 50 N: the 5 Hz band holds 50 / sqrt(2) / M / micro-g = 8.585
    micro-g in every spelling (kN was read as N: 1000 times too small, a false PASS)."""
    from spidersim.cli import main
    f = tmp_path / "mg.yaml"
    f.write_text(UNIT_DIAGRAM.format(amplitude=amplitude))
    out = tmp_path / "out"
    assert main(["run", str(f), "--out", str(out), "--no-plots", "--no-jit"]) == 0
    bands = {round(b["center_hz"], 1): b for b in _strict_json(out / "microgravity.json")
             ["bands"]}
    assert bands[5.0]["level_ug"] == pytest.approx(50 / 4.2e5 / mg.MICRO_G / np.sqrt(2),
                                                   rel=0.01)


@pytest.mark.parametrize("amplitude, unit", [("{value: 1, unit: m}", "m"),
                                             ("{value: 1, unit: N.m}", "N.m")])
def test_a_signal_that_is_not_a_force_is_refused(tmp_path, capsys, amplitude, unit):
    """A position or a torque divided by the station mass is no acceleration: check and run
    refuse it at the section's line (both passed, with a verdict)."""
    from spidersim.cli import main
    f = tmp_path / "mg.yaml"
    f.write_text(UNIT_DIAGRAM.format(amplitude=amplitude))
    for argv in (["check", str(f)], ["run", str(f), "--out", str(tmp_path / "o"),
                                     "--no-plots", "--no-jit"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"mg.yaml:5: microgravity: signal 's.y': the signal is in {unit}, not a " \
               f"force" in err, err
    assert not (tmp_path / "o").exists()


def test_newtons_per_unit():
    assert mg.newtons_per_unit("kN") == 1000.0 and mg.newtons_per_unit("N") == 1.0
    assert mg.newtons_per_unit("?") == 1.0             # no stated unit: taken as N
    with pytest.raises(ValueError, match="the signal is in 1, not a force"):
        mg.newtons_per_unit("1")


def test_a_run_ending_inside_the_window_gives_no_pass(tmp_path, capsys):
    """--t-end inside the microgravity window: the bands the cut window resolves are
    assessed, but the verdict is INCOMPLETE (not PASS: the low bands only the whole window
    resolves were left out; spider.yaml --t-end 2 printed PASS, 78 dB at 20 Hz, where the
    whole run's worst band is 5 Hz at 52.8 dB), microgravity.json passed: null with the
    reason; the same run to the window's end passes."""
    from spidersim.cli import main
    f = tmp_path / "mg.yaml"
    f.write_text(MG_DIAGRAM)
    t_win_end = spidersim.load(str(f)).microgravity["window"][1]
    out = tmp_path / "cut"
    assert main(["run", str(f), "--out", str(out), "--no-plots", "--no-jit",
                 "--t-end", str(t_win_end / 2)]) == 0
    text = capsys.readouterr().out
    assert "verdict: INCOMPLETE" in text and "verdict: PASS" not in text
    assert "not a complete assessment" in text and f"run to {t_win_end:g} s" in text
    js = _strict_json(out / "microgravity.json")
    assert js["passed"] is None and js["verdict"] == "INCOMPLETE" and js["incomplete"]
    assert main(["run", str(f), "--out", str(tmp_path / "whole"), "--no-plots",
                 "--no-jit"]) == 0
    assert "verdict: PASS" in capsys.readouterr().out
