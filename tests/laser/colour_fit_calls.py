"""The arguments the detector passes to the clipped-stripe colour fit, for tests of that fit."""

import numpy as np

from scanrig.laser import colour_fit, stripes

from .colour_synth import stripe_frames


def plain_fit_arguments(monkeypatch, seed):
    """The arguments of the plain colour fit (:func:`scanrig.laser.colour_fit._fit_projected`) of the
    rendered frame of ``seed`` (``stripe_frames``, no laser-off frame): ``y, usable, noise, x, p0,
    lower, upper``."""
    calls = []
    fit_projected = colour_fit._fit_projected

    def spy(*args, **options):
        calls.append(args)
        return fit_projected(*args, **options)

    monkeypatch.setattr(colour_fit, "_fit_projected", spy)
    on, _, _ = stripe_frames(np.random.default_rng(seed))
    stripes.detect_stripe(on, color="red")
    monkeypatch.undo()
    return calls[0]
