"""service.base.heap: freed frame-sized arrays are reused without page faults."""

import json
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
    reason="mallopt thresholds are glibc's",
)

#: A frame's worth of work: four 11 MB arrays (a (3, 3, 480, 640) float32 motion
#: field each) alive at once, touched, freed; 12 frames after a first, then the
#: minor page faults per frame.
PROBE = """
import json, resource, sys
import numpy as np
from service.base.heap import keep_freed_memory
took = keep_freed_memory() if sys.argv[1] == "keep" else None
def frame():
    arrays = [np.empty((3, 3, 480, 640), np.float32) for _ in range(4)]
    for a in arrays:
        a.fill(1.0)
    return sum(float(a[0, 0, 0, 0]) for a in arrays)
frame()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(12):
    frame()
f1 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
print(json.dumps({"took": took, "faults": (f1 - f0) / 12}))
"""


def probe(mode: str) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True,
                         timeout=60, check=True)
    return json.loads(out.stdout)


def test_keep_freed_memory_reuses_frame_buffers_without_faults():
    kept, default = probe("keep"), probe("default")
    assert kept["took"] is True
    # 44 MB is 10,800 pages: reused heap memory faults none of them back in
    assert kept["faults"] < 20
    # by default the heap top beyond twice the largest block freed so far is given
    # back to the kernel, and faults in again next frame (fewer faults than pages
    # where transparent huge pages back it, never near zero)
    assert default["faults"] > 200


def test_keep_freed_memory_clamps_to_what_glibc_accepts():
    from service.base.heap import MMAP_THRESHOLD_MAX, keep_freed_memory

    # a threshold above glibc's ceiling would be refused; it is clamped instead
    assert keep_freed_memory(mmap_threshold=4 * MMAP_THRESHOLD_MAX, trim_threshold=1 << 40)


def test_frame_process_setup_applies_both_settings_here():
    from service.blas import _loaded_openblas
    from service.process import setup_frame_process

    took = setup_frame_process()
    assert set(took) == {"keep_freed_memory", "single_threaded_blas"}
    # this machine runs glibc; numpy's wheels bundle OpenBLAS
    assert took["keep_freed_memory"] is True
    assert took["single_threaded_blas"] is bool(_loaded_openblas())
