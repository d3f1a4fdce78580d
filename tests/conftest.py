"""Suite-wide configuration: the whole suite runs on all cores when pytest-xdist is there.

``python3 -m pytest -q`` (no paths: the ``testpaths`` of pyproject.toml) behaves as
``-n auto --dist loadscope`` when pytest-xdist (the ``test`` extra) is installed: one worker
process per core, each module (with its module-scoped fixtures: a compiled diagram, a study
run, a server) on one worker, so that no expensive fixture is computed twice. Runs of chosen
files or folders stay in one process unless ``-n`` is given; ``-n 0`` (or ``-p no:xdist``)
runs the whole suite in one process, and without pytest-xdist it runs in one process as
before. ``--dist`` given on the command line is kept.

In parallel runs the modules listed in :data:`HEAVY` are handed out first, in that order,
and the many short ones fill in behind them (xdist hands the next module to whichever worker
is about to run out). The order is made for a cold start (empty caches, as in CI), where
numba compiles spidersim's own kernels (the arm's dynamics, the compiled integration loop)
before the first arm diagram runs: one worker starts with the fault study, whose fixture
compiles them (and writes them to the cache), while the other starts with the two long
modules that need neither (the cache tests' interpreted CLI runs, the service's LSODA
jobs); by the time that worker reaches an arm diagram it loads those kernels instead of
compiling them a second time, at the same moment, on the other core. The rest follows by
measured time, longest first, so that no long module starts last while the other core has
nothing left. The order of the tests inside a module is unchanged, and single-process runs
keep the file order.
"""
from __future__ import annotations

import os

import pytest

#: modules handed out first, in this order (see the module docstring): the fault study (its
#: fixture compiles the arm's kernels and the compiled loop), then the two long modules that
#: need neither, then the others of more than 5 s by their time in a cold two-worker run
#: (``--durations``, issue 17 item 7), longest first
HEAVY = (
    "evals/test_fault_study.py",             # impact_fault.yaml: shared kernels + 2 runs
    "solver/test_cache.py",                  # CLI processes, interpreted / LSODA only
    "service/test_persistence_load.py",      # servers, 100 LSODA servo jobs, Dask
    "evals/test_drive_train_studies.py",     # force_control_rigid, payload_capture
    "evals/test_contact_studies.py",         # three ideal-torque arm diagrams, a sweep
    "test_cli.py",
    "evals/test_rotor_reaction.py",
    "test_sweep.py",
    "test_readme.py",
    "service/test_api.py",
    "service/test_cancel.py",                # a server, a 14 s compile cancelled
    "multibody/test_native_import.py",       # fresh processes: an arm diagram, user code
    "solver/test_events.py",
    "hostile/test_corpus.py",
    "test_interrupt.py",
    "evals/test_joint.py",
    "evals/test_contact.py",
    "test_animation.py",
    "diagram/test_codegen_safety.py",
    "service/test_browser.py",
    "test_cli_linearize.py",
    "solver/test_loop.py",
    "evals/test_joint_torque.py",
    "evals/test_arm.py",
    "blocks/test_continuous.py",
    "blocks/test_contract.py",
    "diagram/test_units.py",
)


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """Default ``-n auto`` for whole-suite runs, and ``--dist loadscope`` in collection
    order whenever ``-n`` is on without ``--dist`` (runs before xdist's own ``pytest_cmdline_main``, which turns ``auto`` into the
    number of cores)."""
    if not config.pluginmanager.hasplugin("xdist") or hasattr(config, "workerinput"):
        return                                 # no xdist, or an xdist worker itself
    whole_suite = config.args_source is pytest.Config.ArgsSource.TESTPATHS   # no paths
    if (whole_suite and config.getoption("numprocesses") is None
            and not config.getoption("usepdb") and not config.getoption("collectonly")):
        config.option.numprocesses = "auto"
    if config.getoption("numprocesses") and config.getoption("dist") == "no":
        config.option.dist = "loadscope"
        config.option.loadscopereorder = False   # keep the order below, not most tests first


def pytest_collection_modifyitems(config, items):
    """In an xdist worker (all workers collect the same order): the :data:`HEAVY` modules
    first, in that order; everything else after them in file order."""
    if not hasattr(config, "workerinput"):
        return
    here = os.path.dirname(os.path.abspath(__file__))
    rank = {os.path.join(here, *m.split("/")): k for k, m in enumerate(HEAVY)}
    items.sort(key=lambda it: rank.get(str(it.path), len(HEAVY)))      # stable
