"""Laser trace detection: every spot or stripe candidate, its sub-pixel centre and that centre's sigma.

Modules, bottom to top:

- :mod:`~scanrig.laser.pixels`: pixel blocks, 3 × 3 box sums and per-cell lookups.
- :mod:`~scanrig.laser.noise`: the signal's noise, per cell or per pixel from the laser-off frame.
- :mod:`~scanrig.laser.channels`, :mod:`~scanrig.laser.background`: laser colours and their
  channels, the clip margin; the background level per cell.
- :mod:`~scanrig.laser.clip_level`: the level at which each channel clips, from the frames.
- :mod:`~scanrig.laser.colour_check`: grey frames stored as colour, and frames whose laser shows
  in another colour than the one asked for.
- :mod:`~scanrig.laser.bright_scene`: a scene that itself reaches the clip level: its warning,
  and the clipped pixels there that are no laser.
- :mod:`~scanrig.laser.image`: laser-colour channel, dark-frame subtraction, region of interest,
  saturation mask, background; the signal the detectors see.
- :mod:`~scanrig.laser.luma`: the luma difference of a colour frame and its laser-off frame.
- :mod:`~scanrig.laser.fit`: pixel-integrated Gaussian models and a Levenberg–Marquardt fit
  vectorised over all candidates at once.
- :mod:`~scanrig.laser.crb`: the Cramér–Rao bound of the centre, for tests and benchmarks.
- :mod:`~scanrig.laser.peaks`: candidate finding (strided pre-scan, local maxima, suppression,
  prominence along a line, scan directions).
- :mod:`~scanrig.laser.stripe_candidates`: stripe candidates that rise above both flanks, each
  stripe crossed steeply.
- :mod:`~scanrig.laser.colour_fit`: clipped traces of colour frames, fitted from every channel.
- :mod:`~scanrig.laser.continuity`: stripe candidates ranked by the length of their trace.
- :mod:`~scanrig.laser.spots`, :mod:`~scanrig.laser.stripes`: ``detect_spots`` and
  ``detect_stripe``, one table row per candidate.
- :mod:`~scanrig.laser.traces`: the ``traces.parquet`` schema, reading and atomic writing.
- :mod:`~scanrig.laser.session_detect`: a whole session, in parallel over frames.
- :mod:`~scanrig.laser.overlay`: overlay images of the detections.

The method and its uncertainty model are described in ``docs/detection.md``.
"""
