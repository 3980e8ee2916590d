"""Writer -> parser round trips, third-party reading (pygltflib), atomic writes."""

import io
import os

import numpy as np
import pytest

from pmwm_codec.constants import EXTENSION_NAME, FORMAT_VERSION
from pmwm_codec.format import (
    BaseEvent, ChunkEvent, EndEvent, HeaderEvent, build_pmw, digest, iter_events, read_header, write_pmw,
)
from pmwm_codec.format import glb
from samples import sample_pmw


@pytest.fixture(scope="module", params=["plain", "draco"])
def sample(request):
    return sample_pmw(request.param, chunk_count=4, subdivisions=2, seed=1)


def test_round_trip_gives_the_base_and_every_chunk_payload(sample):
    data, base, payloads, extension = sample
    events = list(iter_events(data))
    header, base_event, *chunk_events, end = events
    assert isinstance(header, HeaderEvent) and header.chunk_count == len(payloads)
    assert header.total_length == len(data)
    assert isinstance(base_event, BaseEvent)
    assert np.array_equal(base_event.positions_int, base.positions_int)
    assert np.array_equal(base_event.faces, base.faces)
    assert [e.index for e in chunk_events] == list(range(len(payloads)))
    assert [e.payload for e in chunk_events] == payloads
    assert end == EndEvent(complete=True, bytes_read=len(data), total_length=len(data),
                           chunks_delivered=len(payloads), chunk_count=len(payloads))


def test_extension_object_carries_version_caller_fields_and_chunk_index(sample):
    data, base, payloads, extension = sample
    header = read_header(data)
    ext = header.extension
    assert ext["version"] == FORMAT_VERSION
    for key, value in extension.items():
        assert ext[key] == value
    views = header.gltf_json["bufferViews"]
    for k, chunk in enumerate(ext["chunks"]):
        view = views[chunk["bufferView"]]
        assert chunk["byteLength"] == view["byteLength"]
        assert chunk["uncompressedLength"] == len(payloads[k])
        assert view.get("byteOffset", 0) % 4 == 0
    assert [c["bufferView"] for c in ext["chunks"]] == sorted(c["bufferView"] for c in ext["chunks"])


def test_extension_is_used_never_required_and_draco_required_only_when_used(sample):
    data, base, _, _ = sample
    gltf = read_header(data).gltf_json
    assert EXTENSION_NAME in gltf["extensionsUsed"]
    assert EXTENSION_NAME not in gltf.get("extensionsRequired", [])
    if base.codec == "draco":
        assert gltf["extensionsRequired"] == ["KHR_draco_mesh_compression"]
        assert "KHR_draco_mesh_compression" in gltf["extensionsUsed"]
    else:
        assert "extensionsRequired" not in gltf


def test_pygltflib_sees_the_extension_and_the_chunk_bytes(sample):
    pygltflib = pytest.importorskip("pygltflib")
    data, base, payloads, _ = sample
    gltf = pygltflib.GLTF2.load_from_bytes(data)
    prim = gltf.meshes[0].primitives[0]
    ext = prim.extensions[EXTENSION_NAME]
    blob = gltf.binary_blob()
    for chunk in ext["chunks"]:
        view = gltf.bufferViews[chunk["bufferView"]]
        stored = blob[view.byteOffset : view.byteOffset + view.byteLength]
        assert digest(stored) == chunk["digest"]
    assert gltf.accessors[prim.attributes.POSITION].count == base.vertex_count


def test_every_bufferview_is_four_byte_aligned_and_in_stream_order(sample):
    data, *_ = sample
    gltf = read_header(data).gltf_json
    offsets = [v.get("byteOffset", 0) for v in gltf["bufferViews"]]
    assert all(o % 4 == 0 for o in offsets)
    assert offsets == sorted(offsets)
    assert len(data) % 4 == 0


def test_write_pmw_to_path_and_file_object_equal_build_pmw(tmp_path):
    _, base, payloads, extension = sample_pmw("plain", 2)
    kwargs = dict(base=base, chunks=payloads, chunk_meta=_meta(base, payloads), extension=extension)
    expected = build_pmw(**kwargs)
    path = tmp_path / "out.pmw"
    assert write_pmw(path, **kwargs) == len(expected)
    assert path.read_bytes() == expected
    buffer = io.BytesIO()
    assert write_pmw(buffer, **kwargs) == len(expected)
    assert buffer.getvalue() == expected
    assert os.listdir(tmp_path) == ["out.pmw"]


def _meta(base, payloads):
    return [{"splits": 1, "vertexCount": base.vertex_count + k + 1, "faceCount": base.face_count + 2 * k + 2,
             "geometricError": 0.0} for k in range(len(payloads))]


def test_atomic_write_keeps_the_old_file_when_the_write_fails_midway(tmp_path, monkeypatch):
    _, base, payloads, extension = sample_pmw("plain", 2)
    path = tmp_path / "out.pmw"
    path.write_bytes(b"old contents")

    def failing_fsync(fd):
        raise OSError("disk full (injected)")

    monkeypatch.setattr(glb.os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="injected"):
        write_pmw(path, base=base, chunks=payloads, chunk_meta=_meta(base, payloads), extension=extension)
    assert path.read_bytes() == b"old contents"
    assert os.listdir(tmp_path) == ["out.pmw"]  # temp file removed


def test_atomic_write_removes_the_temp_file_when_interrupted_between_parts(tmp_path, monkeypatch):
    _, base, payloads, extension = sample_pmw("plain", 2)
    path = tmp_path / "out.pmw"
    real_assemble = glb._assemble

    def assemble_then_break(*args):
        parts = real_assemble(*args)

        class Boom:
            def __len__(self):
                return 0

        parts.insert(3, Boom())  # the file object's write() fails on it after the JSON
        return parts

    monkeypatch.setattr(glb, "_assemble", assemble_then_break)
    with pytest.raises(TypeError):
        write_pmw(path, base=base, chunks=payloads, chunk_meta=_meta(base, payloads), extension=extension)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("field", ["version", "chunks"])
def test_writer_refuses_reserved_extension_fields(field):
    _, base, payloads, extension = sample_pmw("plain", 1)
    with pytest.raises(ValueError, match="set by the writer"):
        build_pmw(base=base, chunks=payloads, chunk_meta=_meta(base, payloads), extension={**extension, field: 1})


def test_writer_refuses_an_extension_the_schema_rejects():
    _, base, payloads, extension = sample_pmw("plain", 1)
    with pytest.raises(ValueError, match="grid"):
        build_pmw(base=base, chunks=payloads, chunk_meta=_meta(base, payloads),
                  extension={**extension, "grid": {"bits": 3, "origin": [0, 0, 0], "step": 1.0}})


def test_writer_refuses_mismatched_chunk_meta():
    _, base, payloads, extension = sample_pmw("plain", 2)
    with pytest.raises(ValueError, match="chunk_meta"):
        build_pmw(base=base, chunks=payloads, chunk_meta=_meta(base, payloads)[:1], extension=extension)
    with pytest.raises(ValueError, match="lacks"):
        build_pmw(base=base, chunks=payloads[:1], chunk_meta=[{"splits": 1}], extension=extension)


def _counted(extension, base, meta):
    """``extension`` with the counts after all of ``meta``'s chunks (the base's without any): what the reader checks."""
    last = meta[-1] if meta else {"vertexCount": base.vertex_count, "faceCount": base.face_count}
    return dict(extension, vertexCount=last["vertexCount"], faceCount=last["faceCount"])


def test_empty_chunk_payload_round_trips():
    _, base, _, extension = sample_pmw("plain", 1)
    meta = _meta(base, [b""])
    data = build_pmw(base=base, chunks=[b""], chunk_meta=meta, extension=_counted(extension, base, meta))
    chunks = [e for e in iter_events(data) if isinstance(e, ChunkEvent)]
    assert [c.payload for c in chunks] == [b""]


def test_file_without_chunks_is_complete_after_the_base():
    _, base, _, extension = sample_pmw("plain", 1)
    data = build_pmw(base=base, chunks=[], chunk_meta=[], extension=_counted(extension, base, []))
    events = list(iter_events(data))
    assert [type(e) for e in events] == [HeaderEvent, BaseEvent, EndEvent]
    assert events[-1].complete


@pytest.mark.parametrize("tmpfile", ["nameless (O_TMPFILE)", "named"])
def test_a_file_whose_name_is_near_the_255_byte_limit_is_published(tmp_path, monkeypatch, tmpfile):
    """The temporary name ``.NAME.<12 hex>.tmp`` of a valid 250-byte NAME was 18 bytes over the limit: the
    write failed with "File name too long" though the name asked for was valid."""
    from pmwm_codec import atomic

    if tmpfile == "named":
        monkeypatch.delattr(atomic.os, "O_TMPFILE", raising=False)
    path = tmp_path / ("é" * 100 + "x" * 46 + ".pmw")  # 250 bytes in UTF-8
    assert len(os.fsencode(path.name)) == 250
    atomic.write_atomic(path, [b"data"])
    assert os.listdir(tmp_path) == [path.name] and path.read_bytes() == b"data"


def test_a_write_over_the_file_size_limit_names_the_file_asked_for(tmp_path):
    """Under ``ulimit -f`` encode, decode and cut said "File too large" without naming any file."""
    import resource
    import subprocess
    import sys

    path = tmp_path / "big.pmw"
    code = ("import sys; from pmwm_codec.atomic import write_atomic\n"
            "try: write_atomic(sys.argv[1], [bytes(64 << 10)])\n"
            "except OSError as exc: print(exc.filename, '|', exc.strerror)\n")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True,
                         preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (16 << 10, 16 << 10)),
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert out.stdout.strip() == f"{path} | File too large"
    assert os.listdir(tmp_path) == []
