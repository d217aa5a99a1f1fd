"""Figure helpers shared by the report's plots: matplotlib's object-oriented API on the Agg canvas, imported
only when a figure is drawn, so that the process's pyplot backend is left alone."""

from __future__ import annotations


def new_figure(width: float, height: float, columns: int = 1):
    """A figure of ``columns`` axes side by side, and those axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(figure)  # attaches itself: the figure renders with Agg whatever the pyplot backend
    axes = figure.subplots(1, columns, squeeze=False)[0]
    return figure, axes


def policy_colours(labels: list[str]) -> dict[str, str]:
    """One colour per policy, the same in both figures."""
    return {label: f"C{i % 10}" for i, label in enumerate(labels)}
