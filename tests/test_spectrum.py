"""Amplitude spectra of ``kind: spectrum`` plots (spidersim.plots) against the closed forms of
the periodic Hann window: the curve's scalloping and the corrected peak labels."""
import numpy as np
import pytest

from spidersim import plots
from spidersim.plots import amplitude_spectrum, hann_peak
from spidersim.sampling import NonUniformRecord

DT, T = 1e-3, 1.0                       # 1000 samples, bins 1 Hz apart


def _tone(f0, amp, phase=0.7, offset=3.0):
    t = np.arange(0, T, DT)
    return t, offset + amp * np.sin(2 * np.pi * f0 * t + phase)


@pytest.mark.parametrize("d", [0.0, 0.1, 0.25, 0.37, 0.5, -0.2, -0.45])
@pytest.mark.parametrize("phase", [0.0, 0.7, 2.0])
def test_curve_shows_the_hann_scalloping(d, phase):
    """A tone of amplitude A at (k + d) bins shows A sinc(d) / (1 - d^2) at bin k on the
    curve (A itself on a bin; 15.1 % low halfway): the closed form hann_peak inverts, to
    1e-4."""
    f0, amp = 120 + d, 0.5
    t, y = _tone(f0, amp, phase)
    f, a = amplitude_spectrum(t, y)
    k = int(np.argmax(a))
    assert round(f[k]) == 120 or (abs(d) == 0.5 and round(f[k]) == 121)
    dk = f0 - f[k]
    assert a[k] == pytest.approx(amp * np.sinc(dk) / (1 - dk ** 2), rel=1e-4)


@pytest.mark.parametrize("f0", [50.0, 120.5, 120.25, 111.4, 222.8, 7.5, 333.33])
@pytest.mark.parametrize("phase", [0.0, 1.1])
def test_corrected_peak_is_the_tones_amplitude(f0, phase):
    """hann_peak gives a lone tone's amplitude to 0.1 % and its frequency to 1e-3 bins, on
    a bin and between bins (the curve alone is up to 15 % low: 120.5 Hz of 0.5 showed
    0.4246)."""
    amp = 0.8
    t, y = _tone(f0, amp, phase)
    f, a = amplitude_spectrum(t, y)
    fk, ak, lone = hann_peak(f, a, int(np.argmax(a)))
    assert lone and ak == pytest.approx(amp, rel=1e-3)
    assert fk == pytest.approx(f0, abs=1e-3 * (f[1] - f[0]))


def test_two_tones_of_spec1():
    """spec1.yaml of the independent check: 3 + 2 sin(2 pi 50 t) + 0.5 sin(2 pi 120.5 t)
    over 0..0.999 s: both peaks labelled with their amplitudes (1 %), the offset removed."""
    t = np.arange(0, 1.0, DT)
    y = 3.0 + 2.0 * np.sin(2 * np.pi * 50 * t) + 0.5 * np.sin(2 * np.pi * 120.5 * t)
    f, a = amplitude_spectrum(t, y, 0.0, 0.999)
    assert a[0] < 0.01          # mean removed (the offset 3 would show 6 at 0 Hz)
    for f0, amp in ((50.0, 2.0), (120.5, 0.5)):
        k = int(np.argmax(np.where(abs(f - f0) < 3, a, 0)))
        fk, ak, lone = hann_peak(f, a, k)
        assert lone and ak == pytest.approx(amp, rel=0.01) and fk == pytest.approx(f0, abs=0.01)


def test_plot_labels_carry_the_corrected_amplitude(monkeypatch, tmp_path):
    """spectrum_plot labels its peaks with hann_peak's frequency and amplitude (not the
    curve's bin height): '120.5 Hz: 0.5 N' for the 120.5 Hz tone of 0.5 N."""
    got = []
    monkeypatch.setattr(plots, "_label_peaks", lambda ax, peaks: got.extend(peaks))
    t, y = _tone(120.5, 0.5)

    class R:
        units = {"s.y": "N"}

        def __init__(self):
            self.t = t

        def __getitem__(self, name):
            return y

    plots.spectrum_plot(R(), {"signals": ["s.y"], "peaks": 1}, str(tmp_path / "s.png"))
    (amp, fk, _colour, unit, lone), = got
    assert amp == pytest.approx(0.5, rel=1e-3) and fk == pytest.approx(120.5, abs=1e-3)
    assert plots.peak_label(fk, amp, unit, lone) == "120.5 Hz: 0.5 N"
    assert plots.peak_label(fk, amp, "?", lone) == "120.5 Hz: 0.5"      # unit unknown


def test_solver_steps_are_refused():
    """A record that is not on a uniform grid (the solver's own steps) is refused, naming
    output_interval; resample=True interpolates a dense jittered record instead (a 10 Hz
    tone of 1 sampled at 2000 random points a second: its peak within 2 %)."""
    rng = np.random.default_rng(3)
    t = np.sort(np.concatenate([[0.0, 2.0], rng.uniform(0, 2, 4000)]))
    y = np.sin(2 * np.pi * 10 * t)
    with pytest.raises(NonUniformRecord, match="output_interval"):
        amplitude_spectrum(t, y)
    f, a = amplitude_spectrum(t, y, resample=True)
    assert hann_peak(f, a, int(np.argmax(a)))[1] == pytest.approx(1.0, rel=0.02)


def test_run_ending_between_grid_points():
    """A uniform record whose last row is off the grid (a stopped run) gives the spectrum
    of the grid's rows."""
    t, y = _tone(50.0, 1.0)
    f, a = amplitude_spectrum(t, y)
    f2, a2 = amplitude_spectrum(np.append(t, T - DT / 3), np.append(y, 0.0))
    np.testing.assert_array_equal(a2, a)


def test_a_drifting_line_keeps_the_curve_height():
    """A line whose frequency drifts over the window (a chirp 20 -> 21 Hz of amplitude 1:
    its power spread over several bins) is no lone tone: the smaller neighbour is far from
    the Hann shape's (1 - d) / (2 + d), so no correction is applied (the label shows the
    curve's height, marked '~'); two tones two bins apart are not corrected either."""
    t = np.arange(0, 4.0, DT)                         # bins 0.25 Hz apart
    y = np.sin(2 * np.pi * (20 * t + 0.125 * t ** 2))
    f, a = amplitude_spectrum(t, y)
    k = int(np.argmax(a))
    fk, ak, lone = hann_peak(f, a, k)
    assert not lone and ak == a[k] and 20 < fk < 21
    assert plots.peak_label(fk, ak, "N", lone).startswith(f"{fk:.1f} Hz: ~")
    y2 = np.sin(2 * np.pi * 20 * t) + 0.8 * np.sin(2 * np.pi * 20.5 * t)
    f, a = amplitude_spectrum(t, y2)
    assert not hann_peak(f, a, int(np.argmax(a)))[2]


SHORT_WINDOW = """\
name: sp
blocks:
  s: {{type: Sine, f: 10}}
simulation: {{t_end: 1, output_interval: 0.01, method: DP54}}
plots:
  - {{kind: spectrum, signals: [s.y], t_min: 0.5, t_max: {t_max}, file: spec.png}}
"""


@pytest.mark.parametrize("t_max, n", [(0.55, 6), (0.56, 7), (0.57, 8)])
def test_window_with_too_few_samples_is_refused(tmp_path, capsys, t_max, n):
    """A window of fewer than 8 samples was silently replaced by the whole record (the plot
    titled '0.5-0.55 s' showed the whole run's 10 Hz line): check and run refuse it at the
    entry's line with the window and the count; 8 samples are drawn."""
    from spidersim.cli import main
    f = tmp_path / "sp.yaml"
    f.write_text(SHORT_WINDOW.format(t_max=t_max))
    if n >= 8:
        assert main(["check", str(f)]) == 0
        return
    for argv in (["check", str(f)], ["run", str(f), "--out", str(tmp_path / "o")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert (f"sp.yaml:6: plots[0]: the spectrum window [0.5, {t_max:g}] s holds {n} "
                f"sample(s) (one every 0.01 s); a spectrum needs at least 8") in err, err
    assert not (tmp_path / "o").exists()


def test_amplitude_spectrum_refuses_a_short_window():
    t = np.arange(0, 1.0001, 0.01)
    with pytest.raises(ValueError, match=r"window \[0.5, 0.55\] s holds 6 sample"):
        amplitude_spectrum(t, np.sin(2 * np.pi * 10 * t), 0.5, 0.55)
