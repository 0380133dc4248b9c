"""What every figure of a report shares: titles wrapped to the width of their axes, so none is clipped."""

from __future__ import annotations

import textwrap


def wrapped_title(ax, text: str, fontsize: float | None = None, **kw) -> None:
    """Set ``ax``'s title, each line of ``text`` wrapped to the axes' width (``kw`` as for ``set_title``)."""
    import matplotlib as mpl
    from matplotlib.font_manager import FontProperties

    size = fontsize if fontsize is not None else FontProperties(size=mpl.rcParams["axes.titlesize"]).get_size_in_points()
    fig = ax.get_figure()
    width_in = ax.get_position().width * fig.get_figwidth()
    chars = max(20, int(width_in * 72 / (0.55 * size)))  # an average glyph of the default font is about 0.55 em wide
    ax.set_title("\n".join(textwrap.fill(line, chars) for line in text.split("\n")), fontsize=size, **kw)


def save_figure(fig, path, **kw) -> None:
    """Lay out, write (no software stamp, so the same figure gives the same bytes) and close a report's figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None}, **kw)
    plt.close(fig)
