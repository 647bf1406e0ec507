"""The figures' shared machinery (manus.runs.figures.common): a long series drawn as what each pixel
column shows keeps every column's extremes (a spike included), and a grid of panels is laid out in
inches without a layout pass."""

import numpy as np
from matplotlib.image import imread

from manus.runs.figures.common import envelope, panels, save, tidy


def test_envelope_keeps_each_columns_minimum_and_maximum_and_a_one_sample_spike():
    n, columns = 100_000, 500
    t = np.arange(n) * 1e-3
    y = np.sin(2 * np.pi * 3.3 * t) + 0.01 * np.random.default_rng(0).normal(size=n)
    y[61_234] = 7.0  # one sample: plain subsampling to 1000 points would miss it
    te, ye = envelope(t, y, columns)
    assert te.size == ye.size == 2 * columns
    assert np.all(np.diff(te) >= 0)  # in time order
    # every column (n / columns samples) by a plain reshape: its extremes are the envelope's
    cols = y.reshape(columns, -1)
    pairs = ye.reshape(columns, 2)
    np.testing.assert_array_equal(pairs.min(axis=1), cols.min(axis=1))
    np.testing.assert_array_equal(pairs.max(axis=1), cols.max(axis=1))
    assert ye.max() == 7.0 and te[np.argmax(ye)] == t[61_234]
    few_t, few_y = t[:1999], y[:1999]  # under 4 samples a column: drawn whole
    assert all(a is b for a, b in zip(envelope(few_t, few_y, columns), (few_t, few_y), strict=True))


def test_panels_size_the_figure_in_inches_and_save_writes_that_many_pixels(tmp_path):
    fig, axes = panels(3, 2, (5.0, 3.0), "a title\nof two lines")
    assert axes.shape == (3, 2)
    w, h = fig.get_size_inches()
    # 2 panels of 5 in with their gaps, 3 of 3 in, plus the margins and the title's two lines
    assert abs(w - 10.2) < 1e-9 and abs(h - 9.58) < 1e-9
    for ax in axes.flat:
        ax.plot(np.arange(10), np.arange(10) ** 2)
    axes[0, 0].semilogy(np.arange(1, 10), np.exp(np.arange(1, 10)))
    tidy(axes)
    assert len(axes[1, 1].yaxis.get_major_locator().tick_values(0, 81)) <= 7
    image = imread(save(fig, tmp_path, "grid.png", tight=False))
    assert image.shape[:2] == (round(100 * h), round(100 * w))  # not cropped: laid out as made
    # the panels stay inside the figure and do not overlap
    boxes = [ax.get_position() for ax in axes.flat]
    assert all(0 < b.x0 < b.x1 < 1 and 0 < b.y0 < b.y1 < 1 for b in boxes)
    assert boxes[0].x1 < boxes[1].x0 and boxes[2].y1 < boxes[0].y0
