"""The source paper's (f, s, Cx, Cy, a, b) model as an OpenCV special case."""

import numpy as np
import pytest

from scanrig.errors import InputError
from scanrig.geometry import Camera
from scanrig.geometry.source_paper import SourcePaperIntrinsics


def test_paper_model_projects_by_its_own_formula():
    paper = SourcePaperIntrinsics(f=1500.0, s=1.02, cx=630.0, cy=500.0, a=-0.2, b=0.003)
    cam = paper.to_camera("c", 1280, 1024)
    rng = np.random.default_rng(5)
    x1, x2 = rng.uniform(-0.3, 0.3, (2, 100))
    r2 = x1**2 + x2**2
    x1d = x1 + paper.a * x1 * r2 + 2 * paper.b * x1 * x2
    x2d = x2 + paper.a * x2 * r2 + paper.b * (r2 + 2 * x2**2)
    expected = np.c_[paper.s * paper.f * x1d + paper.cx, paper.f * x2d + paper.cy]
    np.testing.assert_allclose(cam.project(np.c_[x1, x2, np.ones(100)]), expected, atol=1e-9)
    assert SourcePaperIntrinsics.from_camera(cam) == paper


def test_conversion_back_refuses_terms_the_paper_lacks():
    cam = Camera("c", "opencv5", [1000, 1000, 640, 512, -0.1, 0.02, 0, 0, 0], 1280, 1024)
    with pytest.raises(InputError, match=r"terms the source paper's model lacks: \{'k2': 0.02\}"):
        SourcePaperIntrinsics.from_camera(cam)
