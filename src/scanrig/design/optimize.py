"""Choosing N cameras among candidates: greedy selection, then local exchange refinement.

The objective is the area fraction of the surface *covered* (seen by ``min_views`` cameras and
predicted sigma within the target). Ties, common while fewer than ``min_views`` cameras are
chosen, are broken by the area seen by ``min_views`` cameras, then by one camera. Each candidate's
information is computed once (:func:`~scanrig.design.analysis.camera_terms`); evaluating a set is
then a sum and a closed-form eigenvalue per element.

Refinement: for each chosen camera in turn, try every candidate whose position is among the
``neighbours`` nearest to it (with any lens) and keep the best exchange that improves the
objective; repeat until a full round brings nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError

from .accuracy import sigma_from_information
from .analysis import camera_terms
from .candidates import Candidate, MountingError
from .elements import SurfaceElements, check_back_faces
from .spec import DesignSpec
from .visibility import RayCaster


@dataclass(frozen=True)
class Step:
    """One row of the marginal-gain table (cameras in the order they were added).

    Attributes
    ----------
    candidate : Candidate
    covered_fraction : float
        Area fraction covered within the target by this camera and the ones before it.
    gain : float
        ``covered_fraction`` minus that of the previous row.
    loss_if_removed : float
        Covered fraction lost when only this camera is removed from the final rig.
    """

    candidate: Candidate
    covered_fraction: float
    gain: float
    loss_if_removed: float


@dataclass(frozen=True)
class Selection:
    """The chosen cameras and how the search went.

    Attributes
    ----------
    steps : list of Step
        Chosen cameras in order, with marginal gains.
    covered_fraction : float
        Of the final rig, on the elements the search used.
    refinement_exchanges : int
        Exchanges accepted by the refinement.
    reachable_fraction : float
        Area fraction that at least ``min_views`` candidates use: the most any choice could cover
        (hidden faces, undersides and faces inside touching parts are not reachable).
    """

    steps: list[Step]
    covered_fraction: float
    refinement_exchanges: int
    reachable_fraction: float

    @property
    def candidates(self) -> list[Candidate]:
        return [s.candidate for s in self.steps]


class _Objective:
    """Covered area (and tie-breakers) of candidate subsets, from precomputed per-candidate terms."""

    def __init__(self, used: np.ndarray, info: np.ndarray, areas: np.ndarray, spec: DesignSpec):
        self.used, self.info, self.areas = used, info, areas
        self.min_views, self.target = spec.target.min_views, spec.target.sigma_m
        self.total = float(areas.sum())
        self.evaluations = 0

    def score(self, chosen: list[int]) -> tuple[float, float, float]:
        """``(covered, seen by min_views, seen by one)`` area fractions of the subset."""
        self.evaluations += 1
        if not chosen:
            return (0.0, 0.0, 0.0)
        n_views = self.used[chosen].sum(axis=0)
        sigma = sigma_from_information(self.info[chosen].sum(axis=0), n_views, self.min_views)
        covered = (n_views >= self.min_views) & (sigma <= self.target)
        return (self.areas[covered].sum() / self.total, self.areas[n_views >= self.min_views].sum() / self.total,
                self.areas[n_views >= 1].sum() / self.total)


def select_cameras(candidates: list[Candidate], elements: SurfaceElements, caster: RayCaster, spec: DesignSpec,
                   n_cameras: int, neighbours: int = 8, max_rounds: int = 10, mesh_name: str = "mesh",
                   allow_open: bool = False,
                   progress: Callable[[int, int], None] | None = None) -> Selection:
    """Choose ``n_cameras`` candidates (at distinct positions) maximising the covered area.

    Parameters
    ----------
    candidates : list of Candidate
    elements : SurfaceElements
        The elements the objective counts (a sample of a big mesh is enough).
    caster : RayCaster
        Built on the object's mesh.
    spec : DesignSpec
        Complete (after :func:`~scanrig.design.spec.default_spec`).
    n_cameras : int
        Cameras to choose.
    neighbours : int
        Positions tried around each chosen camera during refinement (0 = no refinement).
    max_rounds : int
        Refinement rounds at most.
    mesh_name : str
        Names the mesh in messages.
    allow_open : bool
        Accept back faces in view (a one-sided surface); they simply do not count.
    progress : callable, optional
        Called as ``progress(done, total)`` while the candidates' terms are computed.

    Returns
    -------
    Selection

    Raises
    ------
    InputError
        If there are fewer candidate positions than ``n_cameras``.
    MeshError
        Unless ``allow_open``, if candidates see back faces (holes, inverted normals; see
        :func:`~scanrig.design.elements.check_back_faces`).
    MountingError
        If no candidate uses any element.
    """
    positions = np.array([c.camera.center_world for c in candidates])
    pose_ids = np.array([c.pose_id for c in candidates])
    n_positions = len(np.unique(pose_ids))
    if n_cameras > n_positions:
        raise InputError(f"cameras: {n_cameras} requested but the mounting region has only {n_positions} "
                         "candidate positions; raise [mounting] n_candidates")
    used = np.zeros((len(candidates), len(elements)), dtype=bool)
    info = np.zeros((len(candidates), len(elements), 3, 3))
    seen_from_behind = np.zeros(len(elements), dtype=bool)
    for i, cand in enumerate(candidates):
        terms = camera_terms(cand.camera, elements, caster, spec)
        used[i], info[i] = terms.used, terms.info
        seen_from_behind |= terms.view.seen_from_behind
        if progress is not None:
            progress(i + 1, len(candidates))
    if not allow_open:
        check_back_faces(elements, seen_from_behind, mesh_name)
    if not used.any():
        raise MountingError("[mounting]: no candidate camera sees any part of the object (all views are outside "
                            "the images, beyond the incidence limit, occluded or out of focus); check look_at, "
                            "the radius and height ranges and the lenses")
    objective = _Objective(used, info, elements.areas, spec)

    chosen: list[int] = []
    for _ in range(n_cameras):
        free = [i for i in range(len(candidates)) if pose_ids[i] not in pose_ids[chosen]]
        chosen.append(max(free, key=lambda i: objective.score(chosen + [i])))

    exchanges = 0
    best = objective.score(chosen)
    for _ in range(max_rounds if neighbours > 0 else 0):
        improved = False
        for slot in range(n_cameras):
            others = chosen[:slot] + chosen[slot + 1:]
            near = np.argsort(np.linalg.norm(positions - positions[chosen[slot]], axis=1), kind="stable")
            near_positions = list(dict.fromkeys(pose_ids[near]))[: neighbours + 1]
            trial = [i for i in range(len(candidates)) if pose_ids[i] in near_positions
                     and pose_ids[i] not in pose_ids[others] and i != chosen[slot]]
            for i in trial:
                score = objective.score(others[:slot] + [i] + others[slot:])
                if score > best:
                    best, chosen = score, others[:slot] + [i] + others[slot:]
                    improved = True
                    exchanges += 1
        if not improved:
            break

    final = best[0]
    steps, previous = [], 0.0
    for k, i in enumerate(chosen):
        covered = objective.score(chosen[: k + 1])[0]
        loss = final - objective.score(chosen[:k] + chosen[k + 1:])[0]
        steps.append(Step(candidates[i], covered, covered - previous, loss))
        previous = covered
    reachable = used.sum(axis=0) >= spec.target.min_views
    return Selection(steps, final, exchanges, float(elements.areas[reachable].sum() / elements.total_area))
