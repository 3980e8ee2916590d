"""Shared fixtures: meshes the code makes itself, and the optional shared corpus."""

from __future__ import annotations

import contextlib
import socket
from pathlib import Path

import pytest

from pmwm_codec import shapes

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
CORPUS = SHARED / "corpus"
WATERMARKS = SHARED / "watermarks"

CORPUS_MESHES = ["cow", "fandisk", "spot", "teapot", "suzanne", "beetle", "stanford-bunny"]


def corpus_path(name: str) -> Path:
    """Path of a shared corpus mesh; skips the test when ../shared is absent."""
    path = CORPUS / name
    if not path.exists():
        pytest.skip(f"shared corpus not available: {path}")
    return path


def watermark_path(name: str) -> Path:
    path = WATERMARKS / name
    if not path.exists():
        pytest.skip(f"shared watermarks not available: {path}")
    return path


@contextlib.contextmanager
def refusing_port():
    """A port of the loopback bound but not listening, so nothing else can take it meanwhile: a connection to it is
    refused.  (A free port found by binding and closing, or a server's port once it is closed, could be taken by
    another process before it was used.)"""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


GENERATED = {
    "sphere": lambda: shapes.icosphere(3, 1.3, noise=0.02),
    "torus": lambda: shapes.torus(40, 20, twist=0.1),
    "grid_with_hole": lambda: shapes.grid(28, 24, hole=True),
    "components": lambda: shapes.components(shapes.icosphere(2, 0.9, noise=0.05), shapes.torus(20, 10), shapes.grid(10, 10, hole=False)),
    "bowtie": lambda: shapes.bowtie(),
    "doubled_faces": lambda: shapes.doubled_faces(),
    "flaps": lambda: shapes.flaps(),
}


def marked_sphere(seed: int, **options):
    """A watermarked icosphere(3) in memory: ``(pmw bytes, key, 16x16 watermark)``."""
    import io

    import numpy as np

    from pmwm_codec.stream import encode_mesh
    from pmwm_codec.watermark.key import WatermarkKey

    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (16, 16)).astype(np.uint8)
    key = WatermarkKey.generate(rng=rng)
    buf = io.BytesIO()
    key = encode_mesh(shapes.icosphere(3), buf, watermark=img, key=key, **options).key  # the key of the file
    return buf.getvalue(), key, img


@pytest.fixture(params=sorted(GENERATED))
def generated_mesh(request):
    """Each of the generated test meshes (closed, open, multi-part, non-manifold, doubled faces)."""
    return request.param, GENERATED[request.param]()


def pytest_addoption(parser):
    parser.addoption(
        "--update-golden",
        action="store_true",
        default=False,
        help="rewrite the conformance files in spec/conformance/ (only after a deliberate format change)",
    )


@pytest.fixture
def update_golden(request):
    return request.config.getoption("--update-golden")
