"""Hostile files: every reader path raises only PmwError subclasses (property-based, fast).

The generators live in ``tools/fuzz.py`` (the long run: ``python tools/fuzz.py --cases 100000``);
here hypothesis drives them for a few seconds per kind.  The sample is a small marked
``.pmw`` (icosphere(3), 16x16 watermark) kept in memory.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tools import fuzz

SETTINGS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None)


@pytest.fixture(scope="module")
def sample():
    s = fuzz.Sample()
    old = fuzz.limit_memory(3 << 30)  # a huge allocation must fail here, not OOM the machine
    yield s
    fuzz.restore_memory(old)


def _only_named_errors(sample, data, block_seed=None):
    rng = None if block_seed is None else np.random.default_rng(block_seed)
    outcome = fuzz.decode_case(bytes(data), sample.key, rng)  # raises anything that is not a PmwError
    assert isinstance(outcome, str)
    return outcome


def test_the_sample_decodes(sample):
    assert _only_named_errors(sample, sample.data) == "ok"
    assert _only_named_errors(sample, sample.rebuild()) == "ok"


@SETTINGS
@given(data=st.data())
def test_byte_mutations(sample, data):
    n = len(sample.data)
    edits = data.draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, 255)), min_size=1, max_size=8))
    b = bytearray(sample.data)
    for i, v in edits:
        b[i] = v
    _only_named_errors(sample, b, data.draw(st.integers(0, 2**32)))


@SETTINGS
@given(cut=st.integers(0, 10**6))
def test_truncations(sample, cut):
    out = _only_named_errors(sample, sample.data[: cut % (len(sample.data) + 1)])
    assert out in ("ok", "TruncatedError")  # a cut file is progress, never corruption


@SETTINGS
@given(data=st.data())
def test_insertions_and_deletions(sample, data):
    n = len(sample.data)
    i = data.draw(st.integers(0, n))
    if data.draw(st.booleans()):
        b = sample.data[:i] + data.draw(st.binary(min_size=1, max_size=64)) + sample.data[i:]
    else:
        b = sample.data[:i] + sample.data[i + data.draw(st.integers(1, 64)):]
    _only_named_errors(sample, b)


@pytest.mark.parametrize("kind", ["splice", "payload", "records", "zstd"])
@SETTINGS
@given(seed=st.integers(0, 2**63 - 1))
def test_generated_cases(sample, kind, seed):
    data = fuzz.make_case(sample, kind, np.random.default_rng(seed))
    _only_named_errors(sample, data, seed)


@SETTINGS
@given(seed=st.integers(0, 2**63 - 1))
def test_crafted_json(sample, seed):
    """Hostile values in the container JSON: counts, offsets, overlapping views, digests, types."""
    data = fuzz.make_case(sample, "json", np.random.default_rng(seed), json_scope="container")
    _only_named_errors(sample, data, seed)


@settings(max_examples=150, deadline=None, database=None)
@given(seed=st.integers(0, 2**63 - 1))
def test_crafted_watermark_json(sample, seed):
    """Hostile values in the watermark and payload objects of the extension: only named errors."""
    data = fuzz.make_case(sample, "json", np.random.default_rng(seed), json_scope="watermark")
    _only_named_errors(sample, data, seed)


def test_crafted_payload_values(sample):
    """Raw payload fields set to hostile values, re-framed with valid digests."""
    import struct

    for k, p in enumerate(sample.payloads):
        for field in range(0, min(len(p), 32), 4):
            for value in (0, 1, 4096, 4097, 2**31, 2**32 - 1):
                b = bytearray(p)
                b[field: field + 4] = struct.pack("<I", value)
                payloads = list(sample.payloads)
                payloads[k] = bytes(b)
                _only_named_errors(sample, sample.rebuild(payloads))


def test_zstd_frame_claiming_gigabytes_is_refused_before_allocating(sample):
    import tracemalloc

    for seed in range(40):
        data = fuzz.make_case(sample, "zstd", np.random.default_rng(seed))
        tracemalloc.start()
        out = _only_named_errors(sample, data)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert out in ("FormatError", "LimitError")
        assert peak < 64 << 20



def test_counts_claimed_past_the_records_cost_the_memory_of_what_is_decoded(sample):
    """An index entry (and every count after it) claiming up to 33M more vertices than the chunk's records
    hold: only named errors, and the arrays follow the splits decoded (they were sized by the claim before)."""
    import tracemalloc

    outcomes = set()
    for seed in range(30):
        data = fuzz.make_case(sample, "claims", np.random.default_rng(seed))
        tracemalloc.start()
        outcomes.add(_only_named_errors(sample, data))
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert peak < 32 << 20, (seed, peak)
    assert outcomes <= {"FormatError", "LimitError"} and outcomes


@pytest.fixture(scope="module", params=["bowtie.welded-draco.packed.v2.pmw", "kissing.welded-draco.packed.v2.pmw"])
def welded(request):
    """A base with Draco's copies of non-manifold vertices, and one whose weld attribute keeps distinct vertices on
    one point apart."""
    from pathlib import Path

    return (Path(__file__).resolve().parents[1] / "spec" / "conformance" / request.param).read_bytes()


@SETTINGS
@given(data=st.data())
def test_byte_mutations_and_cuts_of_a_welded_draco_base_end_in_named_errors(sample, welded, data):
    """The weld's inputs (the Draco base, the POSITION accessor count, baseVertexCount, the weld attribute) edited
    byte by byte."""
    b = bytearray(welded)
    for i, v in data.draw(st.lists(st.tuples(st.integers(0, len(b) - 1), st.integers(0, 255)), max_size=6)):
        b[i] = v
    _only_named_errors(sample, b[: data.draw(st.integers(0, len(b)))])
