"""tools/bits_by_part.py accounts for a payload-version-2 stream's bytes, decision by decision."""

from __future__ import annotations

import contextlib
import io
import json

from pmwm_codec import shapes
from pmwm_codec.cli import main
from tools import bits_by_part


def test_the_parts_add_up_to_the_chunks_bytes_and_leave_the_encode_as_it_was(tmp_path):
    """The costs of every coded decision sum to the chunks' payload bytes, short only of the range coder's
    flush (a few bytes a chunk); the file counted is the library's own encode (same bytes after the count:
    the coder's helpers and numba's switch are put back)."""
    import pmwm_codec

    mesh = shapes.icosphere(4, 1.0, noise=0.03, seed=5)
    cost, size = bits_by_part.costs(mesh, 14)
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, measure=False, grid_bits=14)
    assert size == len(buf.getvalue())
    (tmp_path / "a.pmw").write_bytes(buf.getvalue())
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["info", str(tmp_path / "a.pmw"), "--json"]) == 0
    chunks = json.loads(out.getvalue())["chunks"]
    payload = sum(c["bytes"] for c in chunks)
    coded = sum(cost.values()) / 8
    assert 0 <= payload - coded <= 8 * len(chunks), (payload, coded, len(chunks))
    groups = {name.split(":")[0] for name in cost}
    assert {"mask", "arc-rank", "arc-length", "tangent-1", "tangent-2", "normal"} <= groups, groups
    assert bits_by_part.part(0) == "mask:selection"
