"""Stripe mode: stripe points matched along epipolar lines, the frame's light plane, single views.

A stripe detection measures one number: where the stripe crosses its scan line. Its position
*along* the stripe is not a measurement. Matching a reference detection ``a`` of camera ``i``
with camera ``j`` therefore adds one constraint, not two: the point must project onto ``j``'s
stripe. The classic epipolar "crossing" hides this — the crossing is exactly on ``a``'s epipolar
line by construction, so a two-view point has a zero residual whatever the error, and where the
epipolar line runs nearly along ``j``'s stripe (cameras that see the light sheet edge-on, common
when the laser head and the cameras sit at similar heights) a 0.1 px error across the stripe, or
of the calibration, moves the crossing by pixels and the point by millimetres, while a
covariance interpolated from the detections still predicts a tenth of a millimetre. So:

1. **Stripes.** Each camera's detections are joined into segments between neighbours (closer
   than :data:`~.views.NEIGHBOUR_PX`, not on the same scan line) and into connected *pieces*;
   the local tangent of a detection is the principal direction of its neighbours, and its variance
   *across* the stripe is ``nᵀ Σ n`` (detection covariance plus the calibration floor).
2. **Crossings.** ``a``'s epipolar line is intersected with ``j``'s segments (in undistorted
   normalised coordinates); crossings closer than :data:`~.epipolar.MERGE_PX` are one *branch*
   (the same piece of stripe), represented by the detection ``b`` nearest to the line. Reflections, other
   parts of a curved stripe and the far side of occlusions give further branches.
3. **Hypotheses.** Every choice of at most one branch per other camera is a hypothesis, solved
   by maximum likelihood (Gauss–Newton on pixels): ``a`` constrains the point with its full 2×2
   covariance, each ``b`` only across its stripe (weight ``n nᵀ / σ⊥²``). The covariance
   ``H⁻¹`` is then honest about the epipolar geometry, and the χ² has ``m − 1`` degrees of
   freedom for ``m`` other cameras: three views test each other, two do not. A hypothesis is
   void where the reference ray crosses a matched camera's stripe plane at less than
   ``min_angle_rad`` (no depth), or where the solution projects farther than
   :data:`~.epipolar.MERGE_PX` along ``b``'s stripe from ``b`` (the line constraint is local).
4. **Calibration floor.** Before the frames are solved, the unambiguous three-view hypotheses of
   the whole session estimate how much pixel noise the calibration adds, per camera and ring of
   image radius (:func:`~.floor.estimate_calibration_floor`): a calibration whose target never reached
   the image borders is off by pixels there, which the fixed ``sigma_floor_px`` cannot know.
5. **Light plane.** The frame's plane is fitted robustly (RANSAC with each point's variance
   along the candidate normal, errors-in-variables correction of its extent, weighted least
   squares, block-jackknife uncertainty) to the three-view hypotheses that pass their χ² gate —
   a reflection seen by one camera cannot be among them — or, with two cameras, to the two-view
   ones. Where the reference ray crosses it at ``min_angle_rad`` or more, the plane, with its
   own position uncertainty at the point, is one more measurement: the hypothesis is re-solved
   with it and its χ² (now ``m`` degrees of freedom) must pass the gate. Two-view points are
   tested by the plane only; a secondary reflection, even one every camera sees consistently,
   and a wrong branch are off it. That test has power only where the plane is known: a two-view
   point is kept where the plane's position sigma at the point is at most its own sigma along
   the normal (:data:`~.plane_step.PLANE_SIGMA_RATIO_MAX`). A stripe whose three-view points lie
   on a flat floor fixes a line, not a plane; two-view points off that line — wrong matches
   included, centimetres away with a sigma of tenths of a millimetre — would pass any χ². Without
   a usable plane only three-view points are kept.
6. **One detection, one point.** Consistent hypotheses are accepted greedily — smallest sigma
   first, then most views — and a hypothesis is dropped when one of its detections already
   belongs to an accepted point: no detection supports two points, and a surface point is not
   written once per reference camera.
7. **Single views.** Brightest-on-their-line detections without any crossing in another camera
   (seen by that camera only), on a piece of stripe that other cameras confirm elsewhere (not an
   isolated noise peak or a reflection only this camera sees), are intersected with the plane
   (flag ``PLANE_SINGLE_VIEW``) unless their sigma exceeds :data:`~.single_view.SINGLE_VIEW_SIGMA_RATIO` times
   the frame's median multi-view sigma.
8. **Precision.** Points whose error across their stripe may exceed the accuracy target are left
   out: 0.1 mm (:data:`~.precision.TARGET_SIGMA_M`) unless ``max_sigma_m`` says otherwise. The
   surface normal is perpendicular to the stripe's 3-D tangent, so the bound is the largest
   standard deviation perpendicular to the tangent (from the frame's own points), widened by the
   tangent's angular error — at most ``sigma``. With honest covariances the kept cloud's RMS
   distance to the surface is then at most the target (:mod:`.precision`).

A stripe that is a straight line in space leaves the plane's tilt about that line undetermined;
the plane's position uncertainty (lever arm from its inliers' true extent) grows away from the
line, which widens the gate and the sigma there.

Modules, in the order of the steps: :mod:`.views` (stripes), :mod:`.epipolar` (crossings and
hypotheses), :mod:`.solve` (maximum-likelihood points with covariance), :mod:`.floor`
(calibration floor), :mod:`.plane_step` (light plane), :mod:`.accept` (contradiction, one
detection one point), :mod:`.single_view`, :mod:`.frame` (one frame's assembly),
:mod:`.precision` (the precision cut) and :mod:`.session` (every frame of a session).
"""

from scanrig.reconstruct.stripes.floor import estimate_calibration_floor
from scanrig.reconstruct.stripes.frame import reconstruct_stripe_frame
from scanrig.reconstruct.stripes.session import reconstruct_stripes

__all__ = ["estimate_calibration_floor", "reconstruct_stripe_frame", "reconstruct_stripes"]
