"""The parts of the plot-entry check (spidersim.plots.check_plot_specs), alone on small
entries and logged-signal tables: nothing is simulated or drawn. The hostile corpus checks
the same messages through ``spidersim check``."""
import pytest

from spidersim import plots as P
from spidersim.errors import DiagramError
from spidersim.text.yamlio import load_text

SIZES = {"arm.q": 7, "motor.w": 1}


def test_entry_lines_prefer_the_entrys_own():
    """A mapping read from YAML carries its line; otherwise the list of entry lines gives
    it; past the end of that list there is none."""
    doc = load_text("plots:\n  - {signals: [motor.w]}\n", "f.yaml")
    assert P._entry_line(doc["plots"][0], 0, [9]) == 2
    assert P._entry_line({}, 0, [9]) == 9
    assert P._entry_line({}, 1, [9]) is None


def test_keys_and_kind_are_checked_before_values():
    """Unknown keys are named at their own line, with the list of keys; an unknown kind
    lists the kinds; a valid entry returns its kind (``time`` by default)."""
    doc = load_text("plots:\n  - signals: [motor.w]\n    colour: red\n", "f.yaml")
    with pytest.raises(DiagramError, match="plots\\[0\\]: unknown key 'colour'") as ei:
        P._check_plot_keys(doc["plots"][0], 0, "f.yaml", 2)
    assert ei.value.line == 3
    with pytest.raises(DiagramError, match="unknown kind 'bode' \\(kinds: time, spectrum"):
        P._check_plot_keys({"kind": "bode"}, 0, "f.yaml", 2)
    assert P._check_plot_keys({"signals": []}, 0, None, None) == "time"


@pytest.mark.parametrize("entry,words", [
    ({"t_min": "a"}, "'t_min' must be a finite number of seconds, got 'a'"),
    ({"t_max": True}, "'t_max' must be a finite number"),
    ({"f_max": float("inf")}, "'f_max' must be a finite number of seconds (Hz)"),
    ({"peaks": 21}, "'peaks' must be an integer 0..20, got 21"),
    ({"peaks": 2.0}, "'peaks' must be an integer 0..20"),
    ({"title": [1]}, "'title' must be a text, got a list"),
    ({"ylabel": {}}, "'ylabel' must be a text, got a mapping"),
    ({"t_min": 2, "t_max": 1}, "'t_min' (2 s) must be before 't_max' (1 s)"),
    ({"f_max": 0}, "'f_max' must be a frequency > 0 Hz, got 0"),
    ({"f_max": -5}, "'f_max' must be a frequency > 0 Hz"),
    # math text matplotlib cannot draw failed the plots after the data was written
    ({"title": "$\\sqrt{$"}, "'title' holds math text ($...$) that matplotlib cannot draw"),
    ({"ylabel": "$\\frac{1}{0}$ $$"}, "'ylabel' holds math text"),
])
def test_plot_values(entry, words):
    """Each optional value has its type and range: booleans are not numbers, infinity is
    not a time, peaks 0..20, titles are texts."""
    with pytest.raises(DiagramError) as ei:
        P._check_plot_values(entry, 0, "f.yaml", 4)
    assert words in str(ei.value)


def test_plot_values_that_pass():
    """Numbers (ints too) and texts within range are accepted silently."""
    P._check_plot_values({"t_min": 0, "t_max": 1.5, "f_max": 100, "peaks": 0,
                          "title": 3, "ylabel": "w"}, 0, None, None)
    # math text matplotlib draws, and a lone dollar (not math text) are fine
    P._check_plot_values({"title": "speed $\\omega_m$", "ylabel": "cost in $"}, 0, None,
                         None)


def test_signal_index_checked_only_when_sizes_are_known():
    """``arm.q[6]`` is the last of 7 joints, ``arm.q[7]`` is past the end when sizes are
    known; with only the names of the logged signals the index cannot be checked."""
    P._check_plot_signal("arm.q[6]", 0, SIZES, None, None)
    with pytest.raises(DiagramError, match="'arm.q\\[7\\]': index 7 out of range, 'arm.q' "
                                           "has 7 element"):
        P._check_plot_signal("arm.q[7]", 0, SIZES, None, None)
    P._check_plot_signal("arm.q[7]", 0, set(SIZES), None, None)
    with pytest.raises(DiagramError, match="signal 'motor.ww' is not logged; did you mean "
                                           "motor.w\\?"):
        P._check_plot_signal("motor.ww", 0, SIZES, None, None)


@pytest.mark.parametrize("s,idx", [("arm.q[-1]", -1), ("arm.q[-7]", -7), ("arm.q[ -2 ]", -2),
                                   ("motor.w[-1]", -1)])
def test_a_negative_index_counts_from_the_end(s, idx):
    """``arm.q[-1]`` is the last joint, as in connections (it was 'not logged; did you
    mean arm.q?'); the samples are that column."""
    import numpy as np
    assert P.split_signal(s) == (s.partition("[")[0], idx)
    P._check_plot_signal(s, 0, SIZES, None, None)

    class R:
        def __getitem__(self, name):
            return np.arange(14.0).reshape(2, 7) if name == "arm.q" else np.ones(2)
    want = R()[P.split_signal(s)[0]]
    assert list(P.signal_values(R(), s)) == list(want if want.ndim == 1 else want[:, idx])


@pytest.mark.parametrize("s,words", [
    ("arm.q[-8]", "'arm.q[-8]': index -8 out of range, 'arm.q' has 7 element(s) (0..6, or "
                  "-7..-1 from the end)"),
    ("motor.w[-2]", "index -2 out of range, 'motor.w' has 1 element(s) (0..0, or -1..-1"),
    ("arm.q[١]", "signal 'arm.q[١]': non-ASCII character '١' (U+0661 ARABIC-INDIC DIGIT "
                 "ONE) at character 7: names and indices are ASCII"),
    ("arm.q[𝟏]", "non-ASCII character '𝟏' (U+1D7CF MATHEMATICAL BOLD DIGIT ONE)"),
])
def test_element_errors(s, words):
    """Past either end, and digits of other scripts (``\\d`` read ``[١]`` as 1: now the
    character is named)."""
    with pytest.raises(DiagramError) as e:
        P._check_plot_signal(s, 0, SIZES, "f.yaml", 3)
    assert "plots[0]: " in str(e.value) and words in str(e.value) and e.value.line == 3


@pytest.mark.parametrize("s", ["arm.q[١]", "arm.q[𝟏]", "arm.q[-١]", "arm.q[1_0]"])
def test_split_signal_reads_ascii_digits_only(s):
    """What ``int`` would read but is not written in ASCII digits is no index (the Python
    API's Result.plot goes through split_signal without the plot-entry check)."""
    assert P.split_signal(s) == (s, None)


@pytest.mark.parametrize("s", ["arm.q[1:]", "arm.q[:2]", "arm.q[0:3]", "arm.q[::2]"])
def test_an_element_range_in_a_plot_is_named_as_such(s):
    """A connection's range (``arm.q[1:]``) is not read by a plot: said so, with the two
    forms a plot reads (it was 'not logged; did you mean arm.q?')."""
    with pytest.raises(DiagramError) as e:
        P._check_plot_signal(s, 0, SIZES, None, None)
    assert (f"plots[0]: signal '{s}': a plot takes a whole signal ('arm.q') or one element "
            f"('arm.q[0]'), not an element range" in str(e.value))


def test_plot_entry_needs_signals_and_a_file_for_its_kind():
    """An entry without signals is refused; an animation must be written to a .gif and a
    time plot to an image file."""
    with pytest.raises(DiagramError, match="needs a non-empty list 'signals'"):
        P.check_plot_entry({"signals": []}, 0, SIZES)
    with pytest.raises(DiagramError, match="must end with .png, .svg, .pdf"):
        P.check_plot_entry({"signals": ["motor.w"], "file": "w.gif"}, 0, SIZES)
    with pytest.raises(DiagramError, match="must end with .gif"):
        P.check_plot_entry({"signals": ["arm.q"], "kind": "animation", "file": "a.png"}, 0,
                           SIZES)
    P.check_plot_entry({"signals": ["motor.w", "arm.q[2]"], "file": "w.svg"}, 0, SIZES)


@pytest.mark.parametrize("kind", ["time", "spectrum"])
def test_a_plot_draws_at_most_64_lines(kind):
    """One line and legend entry per element: a 2000-element vector took 16 s to draw and
    8000 took 88 s. 64 lines pass (here 60 + 3 + 1), one more is refused with the count and
    the largest signal; an element ``v.y[3]`` is one line."""
    sizes = {"v.y": 60, "w.y": 3, "x.y": 1, "big.y": 2000}
    P.check_plot_entry({"kind": kind, "signals": ["v.y", "w.y", "x.y"]}, 0, sizes)
    P.check_plot_entry({"kind": kind, "signals": ["big.y[3]"]}, 0, sizes)
    with pytest.raises(DiagramError, match=r"plots\[0\]: the plot would draw 65 lines, one "
                                           r"per element \('v.y' has 60\); at most 64"):
        P.check_plot_entry({"kind": kind, "signals": ["v.y", "w.y", "x.y", "v.y[0]"]}, 0,
                           sizes)


def test_make_plots_refuses_too_many_lines_from_the_api(tmp_path, monkeypatch):
    import spidersim
    d = spidersim.loads("""
blocks:
  c: {type: Constant, value: [1, 2, 3]}
simulation: {t_end: 0.01}
""")
    r = d.simulate(jit=False)
    monkeypatch.setattr(P, "MAX_PLOT_LINES", 2)
    with pytest.raises(DiagramError, match="would draw 3 lines"):
        P.make_plots(r, [{"signals": ["c.y"]}], str(tmp_path))
    assert not list(tmp_path.iterdir())


def test_two_vectors_in_one_panel_are_told_apart(tmp_path, monkeypatch):
    """Two 7-element vectors in one panel (a commanded and a delivered joint torque): each
    line has its own (colour, style), element k of both vectors shares colour k, and each
    vector has its own style (14 lines in one style reused four colours: ctrl[0] and
    tau[3] looked alike)."""
    import spidersim
    r = spidersim.loads("""
blocks:
  a: {type: Constant, value: [1, 2, 3, 4, 5, 6, 7]}
  b: {type: Constant, value: [2, 3, 4, 5, 6, 7, 8]}
simulation: {t_end: 0.01}
""").simulate(jit=False)
    figs = []
    plt = P._pyplot()
    monkeypatch.setattr(plt, "close", lambda fig: figs.append(fig))
    P.time_plot(r, {"signals": ["a.y", "b.y"]}, str(tmp_path / "p.png"))
    lines = figs[0].axes[0].lines
    assert len(lines) == 14
    look = [(ln.get_color(), ln.get_linestyle()) for ln in lines]
    assert len(set(look)) == 14
    assert all(look[k][0] == look[7 + k][0] for k in range(7))
    assert {s for _, s in look[:7]} != {s for _, s in look[7:]}
