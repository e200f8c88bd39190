"""The inverse command's pictures: fit.png (beams over the surface) and flat.png (the flat layout)."""
import numpy as np

from xshells.viz.render import render_fit, render_flat


def _surface():
    x, y = np.meshgrid(np.linspace(-400, 400, 5), np.linspace(-300, 300, 4))
    V = np.stack([x.ravel(), y.ravel(), 1e-4 * (x.ravel() ** 2 + y.ravel() ** 2)], axis=1)
    F = []
    for i in range(3):
        for j in range(4):
            a = 5 * i + j
            F += [[a, a + 1, a + 6], [a, a + 6, a + 5]]
    return V, np.array(F)


def _beams():
    points = np.array([[-300.0, -200, 20], [0, 0, 5], [300, 200, 40], [-300, 200, 30], [300, -200, 90]])
    edges = np.array([[0, 1], [1, 2], [3, 1], [1, 4]])
    return points, edges


def test_fit_axes_carry_the_unit_and_the_colour_scale_its_maximum(tmp_path):
    V, F = _surface()
    points, edges = _beams()
    distances = np.array([3.0, 1.0, 12.0, 7.0, 90.0])  # a free end far off: the colour scale still reaches it
    fig = render_fit(tmp_path / "fit.png", V, F, points, edges, distances, title="joints' fit", unit="mm",
                     joint_max=36.0)
    assert (tmp_path / "fit.png").stat().st_size > 0
    ax = fig.axes[0]
    assert [ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()] == ["x (mm)", "y (mm)", "z (mm)"]
    lc = ax.collections[-1]
    assert lc.get_clim() == (0.0, 90.0)  # the colour bar's top: the largest distance, which its label states
    cbar = fig.axes[1]
    label = cbar.get_xlabel() + cbar.get_ylabel()
    assert "(mm)" in label and "90" in label
    assert any("joints' max 36" in t.get_text() for t in cbar.texts)  # the title's figure, marked on the scale
    # one scale on all three axes: the box's proportions are the data's
    box = np.asarray(ax.get_box_aspect())
    lims = np.array([np.ptp(ax.get_xlim()), np.ptp(ax.get_ylim()), np.ptp(ax.get_zlim())])
    np.testing.assert_allclose(box / box[0], lims / lims[0], rtol=1e-6)


def test_fit_without_a_unit_says_surface_units(tmp_path):
    V, F = _surface()
    points, edges = _beams()
    fig = render_fit(tmp_path / "fit.png", V, F, points, edges, np.ones(len(points)))
    assert fig.axes[0].get_xlabel() == "x (surface units)"


def test_the_colour_bar_keeps_clear_of_a_deep_shells_axis_labels(tmp_path):
    # a shell as deep as Darth Vader's realizable target (1,400 x 1,800 x 650, far from the origin): its x label
    # and ticks ran into the colour bar and the joints' marker
    u, v = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 11))
    V = np.stack([-6200 + 700 * u.ravel(), -12900 + 900 * v.ravel(), -650 * (u.ravel() ** 2 + v.ravel() ** 2) / 2],
                 axis=1)
    F = []
    for i in range(10):
        for j in range(8):
            a = 9 * i + j
            F += [[a, a + 1, a + 10], [a, a + 10, a + 9]]
    points = V[[0, 40, 98, 8, 90]]
    edges = np.array([[0, 1], [1, 2], [3, 1], [1, 4]])
    fig = render_fit(tmp_path / "fit.png", V, np.array(F), points, edges, np.linspace(0, 50, 5), joint_max=33.3)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)  # the closed figure's, drawn again as it was saved
    canvas.draw()
    renderer = canvas.get_renderer()
    to_fig = fig.transFigure.inverted()
    ax, cbar = fig.axes
    bar_top = max(a.get_window_extent(renderer).transformed(to_fig).y1 for a in [cbar, *cbar.texts])
    assert ax.get_tightbbox(renderer).transformed(to_fig).y0 >= bar_top


def test_flat_axes_carry_the_unit_and_hug_the_layout(tmp_path):
    points = np.array([[0.0, 0, 0], [100, 800, 0], [100, 0, 0], [0, 800, 0]])
    edges = np.array([[0, 1], [2, 3]])
    fig = render_flat(tmp_path / "flat.png", points, edges, np.array([0.0, 2.0, 1.0, 3.0]), unit="mm",
                      label="bending stress (MPa)")
    ax = fig.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (mm)", "y (mm)")
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    assert x0 >= -0.05 * 800 and x1 <= 100 + 0.05 * 800 and y0 >= -0.05 * 800 and y1 <= 800 * 1.05
    assert fig.axes[0].collections[0].get_clim() == (0.0, 3.0)
    assert fig.axes[1].get_ylabel() == "bending stress (MPa)"


def test_flat_without_a_unit_or_a_field(tmp_path):
    points = np.array([[0.0, 0], [800, 100], [0, 100], [800, 0]])
    fig = render_flat(tmp_path / "flat.png", points, np.array([[0, 1], [2, 3]]), axes=("along", "across"))
    assert (fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()) == ("along", "across")
    assert len(fig.axes) == 1
