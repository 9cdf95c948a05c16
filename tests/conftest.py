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
