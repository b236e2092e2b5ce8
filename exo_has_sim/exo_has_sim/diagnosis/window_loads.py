"""Each window's own unmeasured load: its shape in time, and the terms its position calls for.

Without a pressure or a load-force signal, :class:`~exo_has_sim.diagnosis.has_plant.HasPlant`
gives each window a load of its own (:meth:`~exo_has_sim.diagnosis.has_plant.HasPlant.predict`):
a polynomial in time across the window, in Legendre terms, each fitted by least squares along
the prediction's sensitivity to it, as the window takes its initial state from the data. Here
are that polynomial's shapes and the least-squares step, held to the loads the cylinder can
carry.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import Legendre

from exo_has_sim.diagnosis.plants import FloatArray


def load_shapes(terms: int, samples: int) -> FloatArray:
    """Return the Legendre terms' shapes at ``samples`` instants across a window.

    Shape (terms, samples): a level, a slope, a bend, ...
    """
    return np.stack([Legendre.basis(d)(np.linspace(-1.0, 1.0, samples)) for d in range(terms)])


def moved(changes: FloatArray, gains: FloatArray) -> FloatArray:
    """Return the outputs' change by windows' load terms.

    ``changes`` per term, shape (..., horizon, output, term); ``gains``, (..., term).
    """
    return np.asarray(np.einsum('...hoi,...i->...ho', changes, gains), dtype=float)


def window_gains(error: FloatArray, changes: FloatArray, guess: float, step: float,
                 bounds: tuple[float, float]) -> FloatArray:
    """Each window's load terms [steps] that fit its position best, within the bounds.

    Parameters
    ----------
    error : FloatArray
        The measured position less the one predicted at the load ``guess`` [m], shape
        (candidates, windows, horizon).
    changes : FloatArray
        The outputs' change per term of one ``step`` [N], shape (candidates or 1, windows,
        horizon, outputs, terms).
    guess : float
        The load the prediction took [N].
    step : float
        The load of one unit of a term [N].
    bounds : tuple[float, float]
        The lowest and highest load the cylinder can carry [N]: a window whose load leaves
        them takes the constant load within them that fits best.

    Returns
    -------
    FloatArray
        Shape (candidates, windows, terms).

    """
    terms = changes.shape[-1]
    basis = changes[..., 0, :]  # the position's sensitivities, (..., horizon, term)
    normal = np.einsum('...ki,...kj->...ij', basis, basis)
    right = np.einsum('...ki,...k->...i', basis, error)
    # A window where the load does not move the position (cavitation, a stop) keeps
    # the guess: the ridge is negligible against any sensitivity that counts.
    ridge = 1e-12 * np.trace(normal, axis1=-2, axis2=-1)[..., None, None] + 1e-300
    with np.errstate(invalid='ignore', over='ignore'):
        gains = np.linalg.solve(np.broadcast_to(normal + ridge * np.eye(terms),
                                                (*right.shape, terms)),
                                right[..., None])[..., 0]
    gains = np.where(np.isfinite(gains), gains, 0.0)
    # The load across each window at a few instants, and the constant fit where it leaves
    # what the cylinder can carry.
    low, high = bounds
    path = guess + step * gains @ load_shapes(terms, 9)
    outside = (path.min(axis=-1) < low) | (path.max(axis=-1) > high)
    if np.any(outside):
        level = right[..., 0] / (normal[..., 0, 0] + ridge[..., 0, 0])
        level = np.clip(level, (low - guess) / step, (high - guess) / step)
        constant = np.zeros_like(gains)
        constant[..., 0] = level
        gains = np.where(outside[..., None], constant, gains)
    return np.asarray(gains, dtype=float)
