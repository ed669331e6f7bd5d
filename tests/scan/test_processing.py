"""Executors: serial, local process pool and a Dask LocalCluster give identical points."""

import logging

import numpy as np
import pytest

from scanrig.scan.processing import (DaskExecutor, FrameJob, LocalPoolExecutor, SerialExecutor, SpotProcessor,
                                     concat_points, frame_jobs, process_frames)
from scanrig.scan.store import ScanStore
from tests.scan import fakerig
from tests.scan.test_loop import _scan


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("session")
    _scan(root)
    store = ScanStore.open(root)
    return frame_jobs(store.frame_paths()), SpotProcessor(fakerig.make_rig())


def _assert_same(a, b):
    assert [f.index for f in a] == [f.index for f in b]
    pa, pb = concat_points(a).vertex_fields(), concat_points(b).vertex_fields()
    for name in pa:
        np.testing.assert_array_equal(pa[name], pb[name], err_msg=name)


def test_local_pool_and_dask_match_serial(session):
    from distributed import Client, LocalCluster

    jobs, process = session
    serial = process_frames(SerialExecutor(), process, jobs)
    assert len(concat_points(serial)) > 10
    with LocalPoolExecutor(2) as pool:
        reverse = process_frames(pool, process, jobs[::-1])          # results follow the job order
        _assert_same(reverse[::-1], serial)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client, DaskExecutor(client) as dask:
        assert dask.n_workers == 2
        _assert_same(process_frames(dask, process, list(reversed(jobs)))[::-1], serial)


def test_frame_with_no_spot_gives_no_point(session, tmp_path):
    from scanrig.io.session import write_image

    jobs, process = session
    dark = {}
    for name in fakerig.make_rig().names:
        dark[name] = tmp_path / f"{name}.png"
        write_image(dark[name], np.full((fakerig.HEIGHT, fakerig.WIDTH), 20, np.uint8))
    out = process(FrameJob(3, "f000003", dark))
    assert (out.index, out.stem, len(out.cloud)) == (3, "f000003", 0)
    assert len(concat_points([])) == 0


def test_unreachable_scheduler():
    from scanrig.errors import InputError

    with pytest.raises(InputError, match=r"cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'"):
        DaskExecutor("tcp://127.0.0.1:9", timeout_s=0.5)
