"""Band analysis of the microgravity assessment against closed forms (issue #13 item 2)."""
import numpy as np
import pytest

from spidersim import microgravity as mg


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


def test_non_uniform_record_is_resampled():
    rng = np.random.default_rng(1)
    t = np.sort(np.concatenate([[0, 20], rng.uniform(0, 20, 40000)]))
    F = np.sin(2 * np.pi * 2 * t)
    a = mg.assess(t, F, 1.0)                                            # M = 1 kg
    k = int(np.argmin(abs(a.bands[:, 1] - 2)))
    assert a.worst[k] == pytest.approx(1 / mg.MICRO_G / np.sqrt(2), rel=0.02)


def test_window_outside_record_is_refused():
    with pytest.raises(ValueError, match="window"):
        mg.assess(np.linspace(0, 1, 100), np.zeros(100), 1.0, window=(0.5, 2))
