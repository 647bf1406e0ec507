"""Columns computed ahead (`Columns.ahead`, a diagnosis's candidates' columns beside its model's
fit) are, bit for bit, those the search computes itself: the same list of values in the same
batches (a Stribeck grid's columns differ in the last bits between a batch of many values and
one value alone)."""

import pickle
import threading

import numpy as np
import pytest

from manus.adaptive import Columns, prepare
from manus.adaptive.diagnosis.candidates import columns_ahead, offered
from manus.adaptive.identify.fit import model_from
from manus.experiments import calibration


@pytest.fixture(scope="module")
def data():
    c = calibration.case(0, "stribeck", rates=(200,))
    return prepare(c.rec), c.start


def test_columns_computed_ahead_are_those_computed_in_place(data):
    d, start = data
    model, _ = model_from(start, d.rec.structure)
    offers, _ = offered(model, d.span(), d.rec.prismatic)
    lists = [list(o.values) for o in offers if o.effect.linear and not model.has(o.effect.name)]
    assert any(o.effect.name == "stribeck" and len(o.values) > 1 for o in offers)
    ahead, here = Columns(d), Columns(d)
    with columns_ahead(ahead, start):
        pass  # (the model's fit would go here; the thread goes on after it)
    for values in lists:
        ahead.prefetch(values)  # (computed by the thread, or waited for)
        here.prefetch(values)
        for v in values:
            np.testing.assert_array_equal(ahead.effect(v), here.effect(v))
    # another batching of the Stribeck grid (what a race without the list's lock could give) agrees to
    # rounding only: the lock is what keeps the bits
    stribeck = next(list(o.values) for o in offers if o.effect.name == "stribeck")
    alone = Columns(d)
    for v in stribeck:
        alone.effect(v)
    assert max(float(np.max(np.abs(alone.effect(v) - here.effect(v)))) for v in stribeck) < 1e-9


def test_a_fit_that_fails_stops_the_columns_ahead(data):
    d, start = data
    cols = Columns(d)
    with pytest.raises(RuntimeError), columns_ahead(cols, start):
        raise RuntimeError("the fit failed")
    assert not any(t.name == "manus-ahead" and t.is_alive() for t in threading.enumerate())


def test_columns_travel_to_another_process_without_their_locks_and_cache(data):
    """A fit shipped to the figure worker carries its IV instruments' columns: they pickle, and
    where unpickled give the same columns again, computed anew."""
    d, start = data
    model, _ = model_from(start, d.rec.structure)
    cols = Columns(d)
    here = cols.model(model)
    with columns_ahead(cols, start):  # (its thread holds the locks meanwhile)
        there = pickle.loads(pickle.dumps(cols))
    assert not there._cache
    np.testing.assert_array_equal(there.model(model), here)
    window = d.window if d.window is not None else d.rows
    other = pickle.loads(pickle.dumps(Columns(d, rows=window)))
    np.testing.assert_array_equal(other.model(model), Columns(d, rows=window).model(model))
