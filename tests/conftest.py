"""Suite-wide configuration: the whole suite runs on all cores when pytest-xdist is there.

``python3 -m pytest -q`` (no paths: the ``testpaths`` of pyproject.toml) behaves as
``-n auto --dist loadscope`` when pytest-xdist (the ``test`` extra) is installed: one worker
process per core, each module (with its module-scoped fixtures: a compiled diagram, a study
run, a server) on one worker, so that no expensive fixture is computed twice. Runs of chosen
files or folders stay in one process unless ``-n`` is given; ``-n 0`` (or ``-p no:xdist``)
runs the whole suite in one process, and without pytest-xdist it runs in one process as
before. ``--dist`` given on the command line is kept.

In parallel runs the modules listed in :data:`HEAVY` are handed out first (longest first),
so that the few long modules (a study fixture of a minute or two) run side by side at the
start and the many short ones fill in behind them, instead of one of them starting last
and leaving the other core idle. The order of the tests inside a module is unchanged, and
single-process runs keep the file order.
"""
from __future__ import annotations

import os

import pytest

#: test modules of a minute or more on one core, longest first (measured with ``--durations``
#: from cold caches: the studies' fixtures, each compiling an arm diagram; a server under load;
#: the cache tests' CLI processes; the rotor-reaction diagrams' compiles; the events' many small
#: diagrams). test_joint.py left the list when its LuGre joint step became compiled.
HEAVY = (
    "evals/test_drive_train_studies.py",
    "evals/test_fault_study.py",
    "service/test_persistence_load.py",
    "evals/test_contact_studies.py",
    "solver/test_cache.py",
    "evals/test_rotor_reaction.py",
    "solver/test_events.py",
    "solver/test_loop.py",
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
    first, longest first; everything else after them in file order."""
    if not hasattr(config, "workerinput"):
        return
    here = os.path.dirname(os.path.abspath(__file__))
    rank = {os.path.join(here, *m.split("/")): k for k, m in enumerate(HEAVY)}
    items.sort(key=lambda it: rank.get(str(it.path), len(HEAVY)))      # stable
