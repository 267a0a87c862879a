"""
Figures 3-5 of the paper, the online stiffness estimate when the run recorded it, the path.

The figures are drawn from a :class:`~hybrid_force_controller.tools.analysis.RunLog`; the
stiffness estimate goes to ``fig6_stiffness.png``; :func:`write_path_figure` draws the path
in the surface plane, desired against actual (``fig7_path.png``, the report's);
:func:`write_normal_figure` the controller's surface normal against the true one
(``fig8_normal.png``, when the run recorded both).

Uses matplotlib's object API on the Agg canvas (no pyplot state, no display needed).
"""
from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

from .analysis import RunLog, surface_axis, tangential_error
from .normal_analysis import normal_error_deg, SETTLE_S, sliding_begins
from .orientation_analysis import tool_tilt_deg
from .path_analysis import path_window, surface_basis

__all__ = ['FIGURE_NAMES', 'NORMAL_FIGURE', 'ORIENTATION_FIGURE', 'PATH_FIGURE',
           'STIFFNESS_FIGURE', 'write_figures', 'write_normal_figure', 'write_orientation_figure',
           'write_path_figure']

FIGURE_NAMES = ('fig3_position.png', 'fig4_force.png', 'fig5_parameters.png')
STIFFNESS_FIGURE = 'fig6_stiffness.png'
PATH_FIGURE = 'fig7_path.png'
NORMAL_FIGURE = 'fig8_normal.png'
ORIENTATION_FIGURE = 'fig9_orientation.png'

_FIGSIZE = (7.0, 4.0)
_DPI = 90
_AXIS_NAMES = 'xyz'


def _new_figure(rows: int = 1) -> tuple[Figure, np.ndarray]:
    """Create a figure with ``rows`` stacked axes sharing the time axis."""
    fig = Figure(figsize=_FIGSIZE, dpi=_DPI, layout='constrained')
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(rows, 1, sharex=True))
    return fig, axes


def _contact_lost_spans(log: RunLog) -> list[tuple[float, float]]:
    """``(t_begin, t_end)`` of every out-of-contact stretch after the first contact."""
    touched = np.flatnonzero(log.in_contact)
    if touched.size == 0:
        return [(float(log.t[0]), float(log.t[-1]))]
    lost = ~log.in_contact
    lost[: touched[0]] = False
    edges = np.diff(np.concatenate(([0], lost.astype(np.int8), [0])))
    begins, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(float(log.t[b]), float(log.t[min(e, log.t.size - 1)]))
            for b, e in zip(begins, ends)]


def _plot_position(log: RunLog, path: Path) -> Path:
    """Fig. 3: position along the surface (actual vs desired) and tangential error."""
    axis = surface_axis(log.n_W)
    fig, (ax_x, ax_e) = _new_figure(2)
    ax_x.plot(log.t, log.x_W[:, axis], label='actual')
    ax_x.plot(log.t, log.x_d_W[:, axis], '--', label='desired')
    ax_x.set_ylabel(f'{_AXIS_NAMES[axis]} [m]')
    ax_x.set_title('Trajectory tracking along the surface')
    ax_x.legend(loc='best')
    ax_e.plot(log.t, 1e3 * tangential_error(log), color='tab:red')
    ax_e.set_ylabel('|e_tan| [mm]')
    ax_e.ticklabel_format(axis='y', useOffset=False)
    ax_e.set_ylim(bottom=0.0)
    ax_e.set_xlabel('t [s]')
    for ax in (ax_x, ax_e):
        ax.grid(True, alpha=0.3)
    fig.savefig(path)
    return path


def _finish(fig: Figure, ax, path: Path, ylabel: str, title: str) -> Path:
    """Label a time plot, add grid and legend, save it."""
    ax.set_xlabel('t [s]')
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc='best')
    fig.savefig(path)
    return path


def _plot_force(log: RunLog, path: Path) -> Path:
    """Fig. 4: normal force actual vs desired, contact losses shaded."""
    fig, (ax,) = _new_figure(1)
    ax.plot(log.t, log.f_W @ log.n_W, label='measured', alpha=0.8)
    if log.f_true_W is not None:
        ax.plot(log.t, log.f_true_W @ log.n_W, label='true', color='black', lw=1.0)
    ax.plot(log.t, log.f_d_W @ log.n_W, '--', label='desired', color='tab:orange')
    for k, (t0, t1) in enumerate(_contact_lost_spans(log)):
        ax.axvspan(t0, t1, color='tab:red', alpha=0.2,
                   label='contact lost' if k == 0 else None)
    return _finish(fig, ax, path, 'n^T f [N]', 'Force tracking along the surface normal')


def _plot_parameters(log: RunLog, path: Path) -> Path:
    """Fig. 5: estimated parameters over time, true values dashed when known."""
    fig, (ax,) = _new_figure(1)
    for i, name in enumerate(log.theta_names):
        (line,) = ax.plot(log.t, log.theta_hat[:, i], label=f'{name} estimate')
        if log.theta_true is not None:
            ax.axhline(log.theta_true[i], ls='--', color=line.get_color(),
                       label=f'{name} true')
    return _finish(fig, ax, path, 'theta_hat', 'Estimation of unknown dynamic parameters')


def _plot_stiffness(log: RunLog, path: Path) -> Path:
    """
    Plot the online stiffness estimate over time (gaps where unknown).

    The true k, when known, is dashed with a +-10 % band.
    """
    fig, (ax,) = _new_figure(1)
    known = ~np.isnan(log.k_hat)
    ax.plot(log.t, log.k_hat, label='estimate k_hat' if known.any() else 'estimate (unknown)')
    if log.k_true is not None:
        ax.axhline(log.k_true, ls='--', color='black', label='true k')
        ax.axhspan(0.9 * log.k_true, 1.1 * log.k_true, color='black', alpha=0.08,
                   label='true k +- 10 %')
    if known.any():
        ax.plot(log.t[known][0], log.k_hat[known][0], 'o', color='tab:blue',
                label=f'first valid, t = {log.t[known][0]:.2f} s')
    return _finish(fig, ax, path, 'k [N/m]', 'Online estimate of the surface stiffness')


def write_figures(log: RunLog, out_dir: str | Path) -> list[Path]:
    """
    Write ``fig3_position.png``, ``fig4_force.png`` and ``fig5_parameters.png``.

    Also ``fig6_stiffness.png`` when the log holds the stiffness estimate (``log.k_hat``).

    Parameters
    ----------
    log : RunLog
        The run to plot.
    out_dir : str or pathlib.Path
        Output directory, created when missing.

    Returns
    -------
    list of pathlib.Path
        The PNG files, in figure order.

    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    writers = (_plot_position, _plot_force, _plot_parameters)
    paths = [write(log, out / name) for write, name in zip(writers, FIGURE_NAMES)]
    if log.k_hat is not None:
        paths.append(_plot_stiffness(log, out / STIFFNESS_FIGURE))
    return paths


def write_path_figure(log: RunLog, out_dir: str | Path, t_start: float = 5.0) -> Path:
    """
    Draw the path in the surface plane, desired against actual, to ``fig7_path.png``.

    Over the path metrics' window (path_analysis.py ``path_window``: while a user's path was
    running, else ``t >= t_start``), in the plane's coordinates (``surface_basis``) relative to
    the window's first desired point, mm. Returns the file's path.
    """
    window, what = path_window(log, t_start)
    if not window.any():
        window = np.ones(log.t.size, dtype=bool)
    u_v = surface_basis(log.n_W)
    origin = log.x_d_W[window][0]
    desired = 1e3 * (log.x_d_W[window] - origin) @ u_v.T
    actual = 1e3 * (log.x_W[window] - origin) @ u_v.T
    fig = Figure(figsize=(6.0, 6.0), dpi=_DPI, layout='constrained')
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(desired[:, 0], desired[:, 1], '--', color='tab:orange', label='desired', lw=1.5)
    ax.plot(actual[:, 0], actual[:, 1], color='tab:blue', label='actual', lw=1.0)
    ax.plot(*desired[0], 'o', color='black', label='start')
    ax.set_aspect('equal', adjustable='datalim')
    names = [_axis_label(u) for u in u_v]
    ax.set_xlabel(f'along {names[0]} [mm]')
    ax.set_ylabel(f'along {names[1]} [mm]')
    ax.set_title(f'Path in the surface plane ({what})')
    ax.legend(loc='best')
    return _save(fig, (ax,), Path(out_dir) / PATH_FIGURE)


def write_normal_figure(log: RunLog, out_dir: str | Path) -> Path | None:
    """
    Draw the controller's normal against the true one to ``fig8_normal.png``.

    Its components (solid) and the truth's (dashed), and the angle between them, with
    sliding's beginning and the start of ``normal_error_deg``'s window (normal_analysis.py).
    None (nothing written) when the run did not record both normals.
    """
    if log.n_hat_W is None or log.n_true_W is None:
        return None
    fig, (ax_n, ax_e) = _new_figure(2)
    for i, name in enumerate(_AXIS_NAMES):
        (line,) = ax_n.plot(log.t, log.n_hat_W[:, i], label=f'n_hat {name}')
        ax_n.plot(log.t, log.n_true_W[:, i], '--', color=line.get_color(), label=f'true {name}')
    ax_n.set_ylabel('normal (base frame)')
    ax_n.set_title('The surface normal: estimate against the truth')
    ax_n.legend(loc='best', ncol=3, fontsize='small')
    ax_e.plot(log.t, normal_error_deg(log), color='tab:red')
    t_slide = sliding_begins(log)
    if np.isfinite(t_slide):
        ax_e.axvline(t_slide, color='black', ls=':', label='sliding begins')
        ax_e.axvline(t_slide + SETTLE_S, color='black', ls='--', label=f'+{SETTLE_S:g} s')
        ax_e.legend(loc='best')
    ax_e.set_ylabel('angle [deg]')
    ax_e.set_ylim(bottom=0.0)
    ax_e.set_xlabel('t [s]')
    return _save(fig, (ax_n, ax_e), Path(out_dir) / NORMAL_FIGURE)


def write_orientation_figure(log: RunLog, out_dir: str | Path,
                             tilt_rad: float = 0.0) -> Path | None:
    """
    Draw how square the tool was to ``fig9_orientation.png``: its tilt and the tilt moment.

    The angle between the tool axis and the true normal (the set tilt dashed), and the true
    moment across the normal, over time. None (nothing written) without a recorded tool axis.
    """
    if log.tool_axis_W is None or log.n_true_W is None:
        return None
    fig, (ax_t, ax_m) = _new_figure(2)
    ax_t.plot(log.t, tool_tilt_deg(log), color='tab:blue', label='tool axis to the normal')
    ax_t.axhline(np.degrees(tilt_rad), color='black', ls='--', label='set tilt')
    ax_t.set_ylabel('tilt [deg]')
    ax_t.set_ylim(bottom=0.0)
    ax_t.set_title('The tool square to the part: its tilt and the tilt moment')
    ax_t.legend(loc='best')
    if log.m_true_W is not None:
        n = log.n_true_W
        m_t = log.m_true_W - np.sum(log.m_true_W * n, axis=1)[:, None] * n
        ax_m.plot(log.t, np.linalg.norm(m_t, axis=1), color='tab:red')
    ax_m.set_ylabel('tilt moment [N m]')
    ax_m.set_xlabel('t [s]')
    return _save(fig, (ax_t, ax_m), Path(out_dir) / ORIENTATION_FIGURE)


def _save(fig: Figure, axes: tuple, path: Path) -> Path:
    """Grid the axes and write the figure to ``path`` (its directory made); return the path."""
    for ax in axes:
        ax.grid(True, alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


def _axis_label(u: np.ndarray) -> str:
    """Return a base axis name (``+x``, ``-y``) when ``u`` is one, else its components."""
    k = int(np.argmax(np.abs(u)))
    if abs(abs(u[k]) - 1.0) < 1e-9:
        return ('+' if u[k] > 0 else '-') + _AXIS_NAMES[k]
    return '(' + ', '.join(f'{c:.2f}' for c in u) + ')'
