import numpy as np
import pytest

from flocking import Model, State


@pytest.fixture
def small_model():
    return Model(n=300, box=6.0, noise=1.0, seed=4)


def min_image(d, box):
    box = np.asarray(box, dtype=float)
    return d - box * np.round(d / box)


@pytest.fixture
def random_state():
    def make(model):
        return State.random(model)

    return make


def pytest_sessionstart(session):
    """The whole default suite on two or more workers: compile its CPU kernels first, each
    once, in as many processes (tests/warm.py says why)."""
    config = session.config
    workers = getattr(config.option, "numprocesses", None)
    if hasattr(config, "workerinput") or config.args_source == pytest.Config.ArgsSource.ARGS:
        return
    if config.option.collectonly:
        return
    if not isinstance(workers, int) or workers < 2:
        return
    import warm

    seconds, errors = warm.compile_kernels(workers)
    report = config.pluginmanager.get_plugin("terminalreporter")
    if report is not None:
        report.write_line(f"the suite's CPU kernels compiled or loaded in {seconds:.0f} s, in {workers} processes")
        for error in errors:
            report.write_line(f"compiling them failed: {error}")
