"""The encoder's OBJ asset reader (pmwm_codec.meshdoc.obj_document) reads the common OBJ a kind of record at once
from its bytes (``_obj_records_fast``), and what it makes of every OBJ -- the glTF document, its buffers, the
notices, the message of a file it refuses -- is what the record-by-record reader (``_obj_records``, which it falls
back to for anything else) makes of it: a differential test over generated OBJs and the corpus's.
"""

from __future__ import annotations

import json
import os
import random
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pmwm_codec import mesh as mesh_mod
from pmwm_codec import meshdoc
from pmwm_codec.mesh import obj_text
from tools.bench_textmesh import torus, write_obj

from conftest import CORPUS

#: The shared corpus's OBJs (none when ``../shared`` is absent: the test is then skipped).
CORPUS_OBJS = sorted(str(p) for p in CORPUS.glob("*.obj")) if CORPUS.is_dir() else []


def _outcome(path) -> tuple:
    """What ``read_source`` makes of ``path``, as comparable values: the document's JSON and buffers' bytes (or a
    mesh's arrays) and the notices, or the type and message of what it raised."""
    try:
        source, notices = meshdoc.read_source(path)
    except Exception as exc:  # noqa: BLE001 (an unexpected one too: both readers must raise it)
        return "raised", type(exc).__name__, str(exc)
    if isinstance(source, tuple):
        gltf, buffers = source
        return "document", json.dumps(gltf, sort_keys=True), [bytes(b) for b in buffers], notices
    return "mesh", source.positions.tobytes(), source.faces.tobytes(), notices


def _both(path, monkeypatch) -> tuple:
    """``(fast path's outcome, record reader's outcome, whether the fast path read it)`` of the OBJ at ``path``: the
    record reader reads its faces record by record too (not a column at a time, which shares its arithmetic with
    the fast path: :func:`~pmwm_codec.meshdoc._face_corners`)."""
    read = []
    fast = meshdoc._obj_records_fast

    def spy(text):
        out = fast(text)
        read.append(out is not None)
        return out

    monkeypatch.setattr(meshdoc, "_obj_records_fast", spy)
    new = _outcome(path)
    monkeypatch.setattr(meshdoc, "_obj_records_fast", lambda text: None)
    columns = meshdoc._obj_faces_columns
    monkeypatch.setattr(meshdoc, "_obj_faces_columns", lambda *args: None)  # faces record by record, each checked
    old = _outcome(path)
    monkeypatch.setattr(meshdoc, "_obj_records_fast", fast)
    monkeypatch.setattr(meshdoc, "_obj_faces_columns", columns)
    return new, old, any(read)


def _number(rng: random.Random, x: float) -> str:
    return rng.choice(["%.6f", "%.9g", "%g", "%.3e", "%.17g"]) % x


#: Malformed or unusual tokens a record may get instead of a number (each read by the record reader's rules).
_ODD_NUMBERS = ["x", "1..2", "nan", "inf", "1e400", "-", "+.5", "1e", ".", "1_0", "0x10", "\u0661", "-0", "1.e5", "1-2"]
_ODD_CORNERS = ["0", "1/2/3/4", "/1", "1//", "a", "99", "-99", "1/-1", "+1", "1///2", "1/1/1/"]


def _random_obj(rng: random.Random) -> str:
    """An OBJ text of random records, usually valid, sometimes with a malformed or unusual one."""
    odd = rng.random() < 0.35
    n = rng.randint(3, 12)
    coloured = rng.random() < 0.3
    colour_scale = rng.choice([1.0, 255.0])
    vt_n = rng.choice([0, n, n + 3]) if rng.random() < 0.85 else 0
    vn_n = rng.choice([0, n, 2])
    form = rng.choice(["v", "v/t", "v//n", "v/t/n"])
    form = {"v/t": "v", "v/t/n": "v//n"}.get(form, form) if not vt_n else form
    form = {"v//n": "v", "v/t/n": "v/t"}.get(form, form) if not vn_n else form
    mixed = rng.random() < 0.1  # some corners of another form (a corner naming no vt, say)
    lines = []
    if rng.random() < 0.6:
        lines.append(rng.choice(["mtllib a.mtl", "mtllib missing.mtl", "mtllib a.mtl b.mtl", "  mtllib\ta.mtl"]))
    if rng.random() < 0.3:
        lines.append(rng.choice(["# a comment", "o thing", "g group", "s 1", "o caf\u00e9"]))
    records = []
    for i in range(n):
        words = [_number(rng, rng.uniform(-5, 5)) for _ in range(3)]
        if coloured and not (odd and rng.random() < 0.1):
            words += [_number(rng, rng.uniform(0, colour_scale)) for _ in range(3)]
        elif rng.random() < 0.03:
            words.append("1")
        records.append(("v", words))
    for _ in range(vt_n):
        records.append(("vt", [_number(rng, rng.uniform(0, 1)) for _ in range(rng.choice([2, 2, 2, 1, 3]))]))
    for _ in range(vn_n):
        records.append(("vn", [_number(rng, rng.uniform(-1, 1)) for _ in range(3)]))
    rng.shuffle(records) if rng.random() < 0.1 else None
    lines += [" ".join([k] + w) for k, w in records]

    def corner(i: int, faces_before: int) -> str:
        v = rng.randint(1, n)
        if rng.random() < 0.15:
            v = v - n - 1  # relative
        t = rng.randint(1, max(vt_n, 1))
        nn = rng.randint(1, max(vn_n, 1))
        f = form if not mixed or rng.random() > 0.2 else rng.choice(["v", "v/t", "v//n", "v/t/n"])
        return {"v": f"{v}", "v/t": f"{v}/{t}", "v//n": f"{v}//{nn}", "v/t/n": f"{v}/{t}/{nn}"}[f]

    quads = rng.random() < 0.3
    for j in range(rng.randint(1, 10)):
        if rng.random() < 0.2:
            lines.append(rng.choice(["usemtl m1", "usemtl m2", "usemtl nothing", "  usemtl m1", "usemtl\tm2"]))
        k = rng.choice([3, 4, 5]) if quads else 3
        if odd and rng.random() < 0.1:
            k = rng.choice([1, 2])
        lines.append("f " + " ".join(corner(i, j) for i in range(k)) + (" # lid" if rng.random() < 0.05 else ""))
        if rng.random() < 0.02:  # a later object's records, after faces
            lines.append("v " + " ".join(_number(rng, rng.uniform(-5, 5)) for _ in range(6 if coloured else 3)))
            n += 1
    if odd:
        at = rng.randrange(len(lines))
        words = lines[at].split(" ")
        if len(words) > 1:
            w = rng.randrange(1, len(words))
            words[w] = rng.choice(_ODD_CORNERS if words[0] == "f" else _ODD_NUMBERS)
            lines[at] = " ".join(words)
        if rng.random() < 0.3:
            lines.insert(rng.randrange(len(lines) + 1), rng.choice(["v", "v ", "vt", "vn 1 2", "f", "f ", "f 1"]))
    if rng.random() < 0.2:  # indented records, tabs after the keyword
        lines = [("  " + l if rng.random() < 0.3 else l.replace(" ", "\t", 1) if rng.random() < 0.2 else l)
                 for l in lines]
    end = rng.choice(["\n", "\n", "\r\n", "\r"])
    return end.join(lines) + (end if rng.random() < 0.8 else "")


def _write_mtl(folder) -> None:
    (folder / "a.mtl").write_text("newmtl m1\nKd 1 0 0\n\nnewmtl m2\nKd 0 0.5 1\nd 0.5\n")
    (folder / "b.mtl").write_text("newmtl m3\nKd 0 1 0\n")


def test_the_fast_obj_reader_makes_what_the_record_reader_makes_of_generated_objs(tmp_path, monkeypatch):
    _write_mtl(tmp_path)
    rng = random.Random(161)
    fast_read = refused = 0
    for case in range(600):
        text = _random_obj(rng)
        path = tmp_path / f"c{case}.obj"
        path.write_bytes(text.encode("utf-8"))
        new, old, took = _both(path, monkeypatch)
        assert new == old, f"case {case}:\n{text}"
        fast_read += took
        refused += new[0] == "raised"
    assert fast_read > 200 and refused > 20  # both paths, and refusals, were exercised


@pytest.mark.parametrize("path", CORPUS_OBJS, ids=[os.path.basename(p) for p in CORPUS_OBJS])
def test_the_fast_obj_reader_makes_what_the_record_reader_makes_of_the_corpus(path, monkeypatch):
    new, old, _ = _both(path, monkeypatch)
    assert new == old


def _peak(path, text) -> int:
    """The most memory Python held while ``obj_document`` read ``text`` (tracemalloc: numpy's arrays count)."""
    tracemalloc.start()
    try:
        doc, _ = meshdoc.obj_document(path, text)
        assert doc is not None
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_textured_obj_is_read_without_a_python_object_per_record(tmp_path):
    """The record reader's lists (a str per record, then per token) took ~8x the OBJ's text at the peak (1,577 MB
    reading a 234 MB OBJ); the bytes reader holds a copy of the text's bytes, a kind of records at a time, and the
    arrays (the corners' indices, 8 bytes each, about the text's size)."""
    path = str(tmp_path / "torus.obj")
    write_obj(path, *torus(20_000))
    text = obj_text(path, "torus.obj")
    assert _peak(path, text) < 6 * len(text)


@st.composite
def valid_objs(draw) -> str:
    """A valid OBJ text, every face's corners of one form (``v``, ``v/t``, ``v//n``, ``v/t/n``) throughout: one to
    three objects, each its ``v`` (3, 4, 6 or 7 numbers, the same count in every record, or mixed counts) / ``vt`` /
    ``vn`` records then faces of 3 to 6 corners (mixed sizes too) naming records read before them, 1-based or
    counted back; ``o`` / ``g`` / ``usemtl`` records, comments, blank lines, tabs, trailing blanks, CRLF or LF, with
    or without a last line end."""
    form = draw(st.sampled_from(["v", "v/t", "v//n", "v/t/n"]))
    widths = draw(st.sampled_from([[3], [4], [6], [7], [3, 4], [3, 6, 7]]))
    sizes = draw(st.sampled_from([[3], [4], [5, 6], [3, 4], [3, 4, 5, 6]]))
    coordinate = st.floats(-1e3, 1e3, allow_nan=False, width=32).map(lambda x: "%.6g" % x)
    blank = st.sampled_from([" ", " ", "\t", "  "])
    lines, read = [], {"v": 0, "vt": 0, "vn": 0}
    for part in range(draw(st.integers(1, 3))):
        if draw(st.booleans()):
            lines.append(draw(st.sampled_from(["o part", "g group", "# a comment", "", "s 1", "usemtl m1"])))
        counts = {"v": draw(st.integers(3, 8)), "vt": draw(st.integers(1, 4)) if "/t" in form else 0,
                  "vn": draw(st.integers(1, 4)) if "n" in form else 0}
        for kind, count in counts.items():
            for _ in range(count):
                width = draw(st.sampled_from(widths)) if kind == "v" else {"vt": 2, "vn": 3}[kind]
                numbers = [draw(coordinate) for _ in range(width)]
                lines.append(kind + draw(blank) + draw(blank).join(numbers) + draw(st.sampled_from(["", " ", "\t"])))
            read[kind] += count

        def index(kind: str) -> str:
            i = draw(st.integers(1, counts[kind]))  # a record of this part, as written or counted back
            return str(read[kind] - counts[kind] + i) if draw(st.booleans()) else str(i - counts[kind] - 1)

        for _ in range(draw(st.integers(1, 6))):
            if draw(st.integers(0, 5)) == 0:
                lines.append(draw(st.sampled_from(["usemtl m1", "usemtl m2", "usemtl none"])))
            corners = [{"v": lambda: index("v"), "v/t": lambda: index("v") + "/" + index("vt"),
                        "v//n": lambda: index("v") + "//" + index("vn"),
                        "v/t/n": lambda: index("v") + "/" + index("vt") + "/" + index("vn")}[form]()
                       for _ in range(draw(st.sampled_from(sizes)))]
            lines.append("f" + draw(blank) + draw(blank).join(corners) + draw(st.sampled_from(["", " ", " # lid"])))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    return end.join(lines) + (end if draw(st.booleans()) else "")


def _record_by_record(text: str, name: str) -> tuple:
    """``_obj_records``' arrays and faces (every face read record by record, each corner checked: not the column
    reader, which shares the fast path's arithmetic)."""
    columns = meshdoc._obj_faces_columns
    meshdoc._obj_faces_columns = lambda *args: None
    try:
        v, vt, vn, mtllibs, faces = meshdoc._obj_records(text, name)
        return v, vt, vn, mtllibs, faces({"m1": 0, "m2": 1})
    finally:
        meshdoc._obj_faces_columns = columns


def _mesh_record_by_record(text: str, name: str) -> tuple:
    """``obj_arrays``' positions and triangles, read record by record (no reader of columns or bytes)."""
    saved = mesh_mod._read_obj_bytes, mesh_mod._read_obj_columns
    mesh_mod._read_obj_bytes, mesh_mod._read_obj_columns = (lambda text: None), (lambda text, lines: None)
    try:
        return mesh_mod.obj_arrays(text, name)
    finally:
        mesh_mod._read_obj_bytes, mesh_mod._read_obj_columns = saved


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(valid_objs())
def test_the_shared_obj_face_reader_takes_every_valid_obj_and_agrees_with_the_record_readers(tmp_path, written):
    """Both OBJ readers of bytes (the document's ``_obj_records_fast``, the mesh's ``_read_obj_bytes``) read faces
    through one piece of code (``ObjLines.face_corners``: corners, forms, relative indices, fans): each reads every
    valid OBJ of one corner form -- polygons of mixed sizes too, which the mesh's had left to the record loop --
    and makes of it what the record-by-record readers make."""
    path = tmp_path / "m.obj"
    path.write_bytes(written.encode("ascii"))
    text = obj_text(str(path), "m.obj")
    fast = meshdoc._obj_records_fast(text)
    assert fast is not None
    got, expected = (*fast[:4], fast[4]({"m1": 0, "m2": 1})), _record_by_record(text, "m.obj")
    for a, b in zip(got[:3] + got[4], expected[:3] + expected[4]):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    assert got[3] == expected[3]
    positions, faces, widest = _mesh_record_by_record(text, "m.obj")
    mesh_fast = mesh_mod._read_obj_bytes(mesh_mod._obj_normalized(text))
    if len({len(r.split()) for r in text.splitlines() if r.split()[:1] == ["v"]}) == 1:  # (one v width: its reader)
        assert mesh_fast is not None
    if mesh_fast is not None:
        assert np.array_equal(mesh_fast[0], positions) and np.array_equal(mesh_fast[1], faces)
        assert mesh_fast[1].dtype == faces.dtype == np.int64 and mesh_fast[2] == widest
