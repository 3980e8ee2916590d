"""Reading a triangle mesh from a PLY file (Stanford's polygon format), ASCII or binary, strictly.

A PLY header names its format (``ascii``, ``binary_little_endian``, ``binary_big_endian``) and its elements
in file order, each with a count and properties: scalars (``property float x``) or lists (``property list uchar
int vertex_indices``: a count, then that many items).  The mesh is the ``vertex`` element's ``x``, ``y``, ``z``
and the ``face`` element's ``vertex_indices`` (or ``vertex_index``) lists, polygons fan-triangulated as an OBJ's
are, or a ``tristrips`` element's strips (-1 restarts a strip); every other element and property is read past
by :func:`read_ply`.  :func:`read_appearance` reads a PLY's appearance besides (:class:`Appearance`): vertex
colours and texture coordinates in their usual spellings, normals, and MeshLab's per-corner ``texcoord`` face
lists, ``texnumber`` and ``comment TextureFile`` header lines; :func:`header_look` tells from the header alone
whether a file has any (:mod:`pmwm_codec.meshdoc` makes such a file a glTF document).

Every record must be what the header declares: an ASCII record holds exactly its properties' values, one
record a line, integers where the type is an integer (a face index ``2.7`` is refused, not truncated), and no
data follows the last element; a binary file is exactly as long as its records.  A file cut short, a list
whose count does not match its items, or a value that does not parse is refused in one line naming it
(:class:`~pmwm_codec.errors.InputFormatError`) -- never read as a smaller or different mesh.  Binary faces
of mixed corner counts (triangles and quads, as MeshLab writes them) are read too.
"""

from __future__ import annotations

import re
import warnings
from array import array
from dataclasses import dataclass, field

import numpy as np

from .errors import InputFormatError

#: PLY scalar type -> numpy type (both spellings of the specification).
TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
#: The names a face's corner list goes by.
FACE_LISTS = ("vertex_indices", "vertex_index")


def read_ply(data: bytes, name: str, max_faces: int) -> tuple:
    """``(positions (n, 3) float64, faces (m, 3) int64)`` of the PLY file ``data``; at most ``max_faces``
    triangles (InputFormatError beyond).  See the module docstring for what is refused."""
    elements, values, _ = _parsed_file(data, name)
    return _mesh(values, elements, name, max_faces)[:2]


#: The spellings of a vertex's colour channels (red, green, blue and an optional alpha), of its texture
#: coordinates (u, v), of its normal, and of a face's per-corner texture coordinates and texture number (as
#: MeshLab writes them, with ``comment TextureFile NAME`` header lines naming the textures in order).
COLOUR_NAMES = (("red", "green", "blue", "alpha"), ("r", "g", "b", "a"),
                ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"))
UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))
NORMAL_NAMES = ("nx", "ny", "nz")
WEDGE_UV, TEXNUMBER = "texcoord", "texnumber"
_TEXTURE_FILE = re.compile(rb"^[ \t]*comment[ \t]+TextureFile[ \t]+([^\r\n]*?)[ \t]*\r?$", re.M | re.I)


@dataclass
class Look:
    """What a PLY header says its file carries besides positions and faces: the property names of the
    vertices' colour (3 or 4) and texture coordinates (2), whether vertices have normals and faces per-corner
    texture coordinates, a texture number or colours (which are not carried), and the texture files its
    comments name."""

    colour: tuple = ()
    uv: tuple = ()
    normal: bool = False
    wedge: bool = False
    texnumber: bool = False
    textures: list = field(default_factory=list)
    face_colour: bool = False

    @property
    def appearance(self) -> bool:
        """Whether the file carries appearance (colours or texture coordinates: a texture needs the latter;
        normals alone are not carried)."""
        return bool(self.colour or self.uv or self.wedge)


def header_look(head: bytes, name: str) -> Look:
    """The :class:`Look` of a PLY file's first bytes (its whole header); InputFormatError for a header
    :func:`read_ply` refuses too."""
    head, _ = _split_header(head, name)
    return _look(head, _header(head.decode("ascii", "replace"), name)[1])


def header_format(head: bytes, name: str) -> str:
    """The format a PLY file's first bytes (its whole header) name: ``ascii``, ``binary_little_endian`` or
    ``binary_big_endian``; InputFormatError for a header :func:`read_ply` refuses too."""
    head, _ = _split_header(head, name)
    return _header(head.decode("ascii", "replace"), name)[0]


def _look(head: bytes, elements: list) -> Look:
    """The :class:`Look` of a header's bytes ``head`` and its ``elements`` (:func:`_header`); the texture
    names in UTF-8, else Latin-1 (as :func:`~pmwm_codec.mesh._mesh_text` reads an OBJ's)."""
    scalars = {e: {p for p, c, _ in props if c is None} for e, _, props in reversed(elements)}
    lists = {e: {p for p, c, _ in props if c is not None} for e, _, props in reversed(elements)}
    vertex, face = scalars.get("vertex", set()), lists.get("face", set())
    colour = next((n if n[3] in vertex else n[:3] for n in COLOUR_NAMES if vertex.issuperset(n[:3])), ())
    return Look(colour, next((n for n in UV_NAMES if vertex.issuperset(n)), ()), vertex.issuperset(NORMAL_NAMES),
                WEDGE_UV in face and bool(face & set(FACE_LISTS)), TEXNUMBER in scalars.get("face", set()),
                [_name(m.group(1)) for m in _TEXTURE_FILE.finditer(head) if m.group(1)],
                any(scalars.get("face", set()).issuperset(n[:3]) for n in COLOUR_NAMES))


def _name(raw: bytes) -> str:
    """A texture file name of a header, backslashes (a Windows exporter's) read as slashes."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.replace("\\", "/")


@dataclass
class Appearance:
    """A PLY's mesh with what it carries besides (:func:`read_appearance`): ``positions`` (n, 3) float64,
    ``faces`` (m, 3) int64; per vertex ``colours`` (n, 3 or 4) in [0, 1], ``uv`` (n, 2) and ``normals``
    (n, 3), or None; per triangle corner ``wedge`` (m, 3, 2) texture coordinates (NaN for a triangle of a
    strip, which has none) and per triangle ``texnumber`` (m,) int64 (-1 for a strip's), or None; the
    ``textures`` the header names, and whether faces have colours (not read).  Texture coordinates are the
    file's (v grows upwards)."""

    positions: np.ndarray
    faces: np.ndarray
    colours: np.ndarray | None
    uv: np.ndarray | None
    normals: np.ndarray | None
    wedge: np.ndarray | None
    texnumber: np.ndarray | None
    textures: list
    face_colour: bool = False


def read_appearance(data: bytes, name: str, max_faces: int) -> Appearance:
    """The :class:`Appearance` of the PLY file ``data`` (read and refused as :func:`read_ply` reads and
    refuses it).  Colours of an integer type are read as glTF reads normalized integers (``uchar`` / 255,
    ``ushort`` / 65535, ``char`` / 127, ...), floats as they are; both clamped to [0, 1].  InputFormatError
    for a face whose ``texcoord`` list is not two values a corner."""
    elements, values, head = _parsed_file(data, name)
    positions, faces, found, fans = _mesh(values, elements, name, max_faces)
    look = _look(head, elements)
    kinds = {p: kind for p, c, kind in next((props for e, _, props in elements if e == "vertex"), [])}
    vertex, face = found["vertex"], found.get("face", {})
    colours = uv = normals = wedge = texnumber = None
    if look.colour:
        colours = _unit(np.stack([_carried(vertex[p], "vertex", "colour", name) for p in look.colour], 1),
                        [kinds[p] for p in look.colour])
    if look.uv:
        uv = np.stack([_carried(vertex[p], "vertex", "texture coordinate", name) for p in look.uv], axis=1)
    if look.normal:
        normals = np.stack([np.asarray(vertex[p], np.float64) for p in NORMAL_NAMES], axis=1)
    strips = len(faces) - (0 if fans is None else len(fans[0]))
    if look.wedge and fans is not None:
        corners = next(found["face"][p] for p in FACE_LISTS if p in face)[0]
        lengths, items = face[WEDGE_UV]
        bad = np.flatnonzero(lengths != 2 * corners)
        if len(bad):
            i = int(bad[0])
            raise InputFormatError(f"{name}: PLY face {i} has {int(lengths[i])} texcoord values for its "
                                   f"{int(corners[i])} corners (two a corner)")
        pairs = _carried(items, "face", "texcoord value", name, np.cumsum(lengths)).reshape(-1, 2)
        wedge = np.concatenate([pairs[fans[0]], np.full((strips, 3, 2), np.nan)])
    if look.texnumber and fans is not None:
        texnumber = np.concatenate([np.asarray(face[TEXNUMBER], np.int64)[fans[1]], np.full(strips, -1, np.int64)])
    return Appearance(positions, faces, colours, uv, normals, wedge, texnumber, look.textures, look.face_colour)


def _carried(values: np.ndarray, element: str, what: str, name: str, ends=None) -> np.ndarray:
    """``values`` as float64, refused (InputFormatError naming the first record: the one whose list ends past
    it where ``ends`` gives where each record's list ends) where one is a number float32 does not carry (NaN,
    infinite, beyond its range), as an OBJ's are: glTF's attributes are float32."""
    values = np.asarray(values, np.float64)
    bad = ~(np.abs(values) <= np.finfo(np.float32).max)
    if bad.any():
        at = int(np.argmax(bad))
        record = at if ends is None else int(np.searchsorted(ends, at, "right"))
        raise InputFormatError(f"{name}: PLY {element} {record:,} has a {what} float32 cannot carry (NaN, infinite "
                               "or beyond 3.4e38)")
    return values


def _unit(values: np.ndarray, kinds: list) -> np.ndarray:
    """Colours (n, k) float64 whose channel ``j`` was of numpy type ``kinds[j]``, in [0, 1]
    (:func:`read_appearance`): an integer channel over its type's largest value (glTF's normalized integers);
    float channels as they are -- but over 255 where one of them reaches 2, the rule an OBJ's colours follow
    (exporters that write ``property float red`` in 0..255: a 0..1 colour a rounding over 1 is not one)."""
    values = np.array(values, np.float64)
    floats = [j for j, kind in enumerate(kinds) if kind[0] not in "iu"]
    for j, kind in enumerate(kinds):
        if kind[0] in "iu":
            values[:, j] /= np.iinfo(kind).max
    if floats and len(values) and values[:, floats].max() >= 2.0:
        values[:, floats] /= 255.0
    return np.clip(values, 0.0, 1.0)


def _split_header(data: bytes, name: str) -> tuple:
    """``(the header's bytes, where the records start)`` of a PLY file's bytes (or of its first bytes)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputFormatError(f"{name}: not a PLY file (no 'ply' ... 'end_header' header)")
    body = data.index(b"\n", end) + 1 if b"\n" in data[end:] else len(data)
    return data[:end], body


def _parsed_file(data: bytes, name: str) -> tuple:
    """``(elements (:func:`_header`), each element's values, the header's bytes)`` of a PLY file's bytes."""
    head, body = _split_header(data, name)
    fmt, elements = _header(head.decode("ascii", "replace"), name)
    if fmt == "ascii":
        values = _ascii_elements(data[body:], elements, name)
    else:
        values = _binary_elements(data[body:], elements, "<" if fmt == "binary_little_endian" else ">", name)
    return elements, values, head


def _header(text: str, name: str) -> tuple:
    """``(format, [(element, count, [(property, None or count type, type)])])`` of a PLY header's text."""
    fmt, elements = None, []
    for line in text.splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3 and words[1] in ("ascii", "binary_little_endian",
                                                                        "binary_big_endian"):
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in TYPES:
            elements[-1][2].append((words[2], None, TYPES[words[1]]))
        elif (words[0] == "property" and elements and len(words) == 5 and words[1] == "list"
              and words[2] in TYPES and words[3] in TYPES and TYPES[words[2]][0] in "iu"):
            elements[-1][2].append((words[4], TYPES[words[2]], TYPES[words[3]]))
        else:
            raise InputFormatError(f"{name}: malformed PLY header line {line.strip()[:60]!r}")
    if fmt is None:
        raise InputFormatError(f"{name}: its PLY header names no format (ascii, binary_little_endian or "
                               "binary_big_endian)")
    return fmt, elements


def _ascii_elements(body: bytes, elements: list, name: str) -> list:
    """Each element's values (:func:`_values`) from ASCII records, one a line (blank lines skipped).  The
    lines are counted with numpy, and each element's text parsed on its own (:func:`_ascii_records`)."""
    bad = _NOT_NUMERIC.search(body)
    if bad is not None:
        raise InputFormatError(f"{name}: byte {bad.group()!r} in the records of an ASCII PLY (numbers only)")
    per_line, ends = _tokens_per_line(body)
    at, out = 0, []
    for element, count, props in elements:
        if not props:  # an element of no properties holds no data
            out.append({})
            continue
        widths = per_line[at: at + count]
        if len(widths) < count:
            raise InputFormatError(f"{name}: PLY declares {count:,} {element} records but holds {len(widths):,} "
                                   "lines for them (cut short, or not one record a line)")
        text = body[int(ends[at - 1]) if at else 0: int(ends[at + count - 1]) if count else 0]
        out.append(_ascii_records(text, widths, props, element, name, at))
        at += count
    if at < len(per_line):
        line = body[int(ends[at - 1]) if at else 0: int(ends[at])]
        raise InputFormatError(f"{name}: data after the last PLY element (line {at + 1} after the header: "
                               f"{b' '.join(line.split()).decode()[:60]!r})")
    return out


def _tokens_per_line(body: bytes) -> tuple:
    """``(tokens (lines,) int64, ends (lines,) int64)``: the whitespace-separated tokens on each line of ``body``
    that holds any, and where that line ends (its line feed's offset, or the end of ``body``).  Each token's
    line is the count of line feeds before its first byte, found among the line feeds' offsets (a count over
    every byte, an int64 a byte, took 8 bytes of memory per byte of the file: 3.3 GB for a 417 MB PLY)."""
    data = np.frombuffer(body, np.uint8)
    if not len(data):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    start = _token_starts(data)
    newlines = np.flatnonzero(data == 10)
    counts = np.bincount(np.searchsorted(newlines, start), minlength=len(newlines) + 1)
    held = counts > 0
    return counts[held], np.append(newlines, len(data))[held]


def _token_starts(data: np.ndarray) -> np.ndarray:
    """(tokens,) int64: where each whitespace-separated token of the bytes ``data`` (uint8) starts."""
    space = (data >= 9) & (data <= 13)  # line feed among them
    space |= data == 32
    start = np.flatnonzero(~space[1:] & space[:-1]) + 1  # a token's first byte: not white space, after white space
    return np.concatenate([[0], start]) if len(data) and not space[0] else start


def _integer_columns_plain(text: bytes, width: int, columns: list) -> bool:
    """Whether every token of the ``columns`` of records of ``width`` tokens in ``text`` is a sign and digits
    alone (``2.0``, ``2e0`` and ``inf`` are no integer type's values, as the token reader refuses them)."""
    data = np.frombuffer(text, np.uint8)
    plain = ((data >= 48) & (data <= 57)) | (data == 43) | (data == 45) | ((data >= 9) & (data <= 13)) | (data == 32)
    other = np.flatnonzero(~plain)
    del plain
    column = (np.searchsorted(_token_starts(data), other, "right") - 1) % width
    return not np.isin(column, columns).any()


def parsed_numbers(text, dtype) -> np.ndarray | None:
    """The whitespace-separated numbers of ``text`` (bytes-like) as a (count,) ``dtype`` (int64 or float64) array,
    parsed by numpy at once, or None when a token is not one number of that type -- the caller then reads the
    tokens one by one, and names what is wrong.  Each token gives one value or stops the parse (a sign alone,
    which numpy reads as 0 at the end or joins to the next token, gives None), so a caller that finds as many
    values as tokens has the tokens' values."""
    if _LONE_SIGN.search(memoryview(text)) is not None:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # (a token that does not parse: numpy warns and stops)
            return np.fromstring(text if isinstance(text, bytes) else bytes(text), dtype, sep=" ")
    except (ValueError, Warning):
        return None


#: A sign that is a token of its own (``+`` or ``-`` before white space or the end).
_LONE_SIGN = re.compile(rb"[+-](?![^\s])")
#: What no ASCII PLY record holds: a byte other than ASCII letters, digits, signs, points and white space
#: (numpy and Python read ``1_0`` as 10 and Arabic-Indic digits as digits).
_NOT_NUMERIC = re.compile(rb"[^0-9A-Za-z+\-.\s]")


def _ascii_records(text: bytes, widths: np.ndarray, props: list, element: str, name: str, first: int) -> dict:
    """One element's values (:func:`_values`) from its records' ``text`` (``widths[i]`` tokens on record i, the
    first of them line ``first`` after the header): records of one shape (every list as long as in the first)
    at once -- parsed straight from the text by numpy when every value is an integer or every one a float
    (:func:`_uniform_values`), else from its tokens -- otherwise record by record."""
    if not len(widths):
        return _values([], props)
    lengths = _list_lengths(text.split(None, int(widths[0]))[: widths[0]], props)
    uniform = lengths is not None and (widths == widths[0]).all()
    if uniform:
        out = _uniform_values(text, len(widths), int(widths[0]), props, lengths)
        if out is not None:
            return out
    tokens = text.split()
    if uniform:
        try:
            return _columns(np.array(tokens).reshape(len(widths), -1), props, lengths)
        except ValueError:
            pass  # the record that does not parse is named below
    try:  # lists of mixed lengths: the tokens sorted by property record by record, each property parsed at once
        return _sorted_columns(tokens, widths, props)
    except (ValueError, IndexError):
        pass
    rows, at = [], 0
    for i, w in enumerate(widths.tolist()):
        words = tokens[at: at + w]
        row = _ascii_record(words, props)
        if row is None:
            raise InputFormatError(f"{name}: malformed PLY {element} record (line {first + i + 1} after the header): "
                                   f"{b' '.join(words).decode()[:60]!r}")
        rows.append(row)
        at += w
    return _values(rows, props)


def _uniform_values(text: bytes, count: int, width: int, props: list, lengths: list):
    """:func:`_columns`' values of ``count`` records of ``width`` tokens each, every list ``lengths[k]`` long,
    parsed from ``text`` by numpy at once (no token list: a Python bytes object a token took ~5x the file's
    size) when every value is of an integer type, or the element has no list (integers beside floats read as
    float64, each of their tokens checked to be a plain integer: :func:`_integer_columns_plain`); None
    otherwise, or when a token does not parse, a value is out of its type's range or a list's count differs
    (the token reader then reads or names it): :func:`parsed_numbers`."""
    integer = [kind[0] in "iu" for _, _, kind in props]
    lists = any(c is not None for _, c, _ in props)
    if lists and not all(integer):
        return None  # (a list of floats, or beside floats: the token reader)
    values = parsed_numbers(text, np.int64 if all(integer) else np.float64)
    if values is None or values.size != count * width:
        return None
    try:
        table = values.reshape(count, width)
        if any(integer) and not all(integer) and not (
                (np.abs(table[:, integer]) <= 1 << 32).all() and _integer_columns_plain(text, width, np.flatnonzero(integer))):
            return None  # (an integer of 32 bits, PLY's widest, is exact in float64)
        return _columns(table, props, lengths)
    except (ValueError, Warning):
        return None


def _sorted_columns(tokens: list, widths: np.ndarray, props: list) -> dict:
    """:func:`_values` of records whose lists differ in length: one pass over the records puts each token with
    its property (no number parsed in it), then each property's tokens are parsed at once (:func:`_parsed`);
    ValueError when a record does not fit ``props`` or a value does not parse (then named record by record)."""
    scalars = [[] for _ in props]
    lengths = [[] for _ in props]
    at = 0
    for w in widths.tolist():
        end = at + w
        for j, (_, count, _) in enumerate(props):
            if count is None:
                scalars[j].append(tokens[at])
                at += 1
                continue
            if not tokens[at].isdigit():
                raise ValueError("a list count that is not a count")
            k = int(tokens[at])
            scalars[j].extend(tokens[at + 1: at + 1 + k])
            lengths[j].append(k)
            at += 1 + k
        if at != end:
            raise ValueError("a record that does not fit its properties")
    out = {}
    for j, (p, count, kind) in enumerate(props):
        values = _parsed(np.array(scalars[j]), kind) if scalars[j] else np.zeros(0, np.int64)
        out[p] = values if count is None else (np.array(lengths[j], np.int64), values)
    return out


def _list_lengths(words: list, props: list):
    """The list lengths of the record ``words`` (strings) of ``props``, or None when they do not fit it."""
    at, lengths = 0, []
    for _, count, _ in props:
        if count is None:
            at += 1
            continue
        if at >= len(words) or not words[at].isdigit():  # (str or bytes)
            return None
        lengths.append(int(words[at]))
        at += 1 + lengths[-1]
    return lengths if at == len(words) else None


def _columns(table: np.ndarray, props: list, lengths: list) -> dict:
    """:func:`_values` of records of one shape, ``table`` (count, w) of str, or of int64 / float64 values already
    parsed, each list ``lengths[k]`` long;
    ValueError when a value does not parse as its type or a list's count is not its length."""
    at, k, out = 0, 0, {}
    for p, count, kind in props:
        if count is None:
            out[p] = _parsed(table[:, at], kind)
            at += 1
            continue
        if not (table[:, at] == np.array(str(lengths[k])).astype(table.dtype)
                if table.dtype.kind in "SU" else table[:, at] == lengths[k]).all():
            raise ValueError("a list's count differs")
        items = _parsed(table[:, at + 1: at + 1 + lengths[k]], kind)
        out[p] = (np.full(len(table), lengths[k], np.int64), items.reshape(-1))
        at, k = at + 1 + lengths[k], k + 1
    return out


def _parsed(tokens: np.ndarray, kind: str) -> np.ndarray:
    """``tokens`` (str array, or int64 / float64 values) as the declared numpy ``kind``, widened to int64 or float64: ValueError for an
    integer type's token that is not an integer (``2.7``) or out of its range; a ``float`` past float32's
    range is infinite, as a binary file's would be (refused later, as every infinite coordinate is)."""
    if kind[0] in "iu":
        values = tokens.astype(np.int64)  # (a float64 table holds no integer type's values: _uniform_values)
        info = np.iinfo(kind)
        if values.size and (values.min() < info.min or values.max() > info.max):
            raise ValueError("an integer out of its type's range")
        return values
    values = tokens.astype(np.float64)
    if kind == "f4":
        with np.errstate(over="ignore"):
            values = values.astype(np.float32).astype(np.float64)
    return values


def _ascii_record(words: list, props: list):
    """One ASCII record's values (a list: a number per scalar property, an array per list), or None when the
    words are not exactly the properties' values."""
    at, row = 0, []
    try:
        for _, count, kind in props:
            if count is None:
                row.append(_parsed(np.array(words[at: at + 1]), kind)[0])
                at += 1
                continue
            k = int(words[at])
            items = words[at + 1: at + 1 + k]
            if k < 0 or len(items) < k:
                return None
            row.append(_parsed(np.array(items), kind))
            at += 1 + k
    except (IndexError, ValueError):
        return None
    return row if at == len(words) else None


def _values(rows: list, props: list) -> dict:
    """``{property: (count,) array}`` for scalars, ``{property: (lengths (count,) int64, items (sum,))}`` for
    lists, from records read one at a time (``rows``: a list per record, as :func:`_ascii_record`'s)."""
    out = {}
    for j, (p, count, _) in enumerate(props):
        column = [row[j] for row in rows]
        if count is None:
            out[p] = np.array(column)
        else:
            out[p] = (np.array([len(v) for v in column], np.int64),
                      np.concatenate(column) if column else np.zeros(0, np.int64))
    return out


def _binary_elements(body: bytes, elements: list, order: str, name: str) -> list:
    """Each element's values (:func:`_values`) from binary records (byte ``order`` ``<`` or ``>``)."""
    at, out = 0, []
    for element, count, props in elements:
        values, at = _binary_records(body, at, count, props, order, element, name)
        out.append(values)
    if at != len(body):
        raise InputFormatError(f"{name}: {len(body) - at:,} bytes after the last PLY element")
    return out


def _binary_records(body: bytes, at: int, count: int, props: list, order: str, element: str, name: str) -> tuple:
    """``(values, end)``: ``count`` records of ``props`` from byte ``at``: at once when every list has the
    length the first record's has, else record by record."""
    short = InputFormatError(f"{name}: PLY declares {count:,} {element} records but the file ends before them "
                             "(cut short)")
    if not props:  # an element of no properties holds no data
        return {}, at
    lengths, pos = [], at
    for _, c, kind in props if count else []:  # the first record's list lengths
        if c is not None:
            if pos + np.dtype(c).itemsize > len(body):
                raise short
            lengths.append(int(np.frombuffer(body, order + c, 1, pos)[0]))
            pos += np.dtype(c).itemsize + lengths[-1] * np.dtype(kind).itemsize
        else:
            pos += np.dtype(kind).itemsize
    if count == 0 or min(lengths, default=0) < 0:
        if count:
            raise InputFormatError(f"{name}: a PLY {element} list of negative length")
        return _values([], props), at
    fixed = _record_dtype(props, lengths, order)
    if at + count * fixed.itemsize <= len(body):
        rec = np.frombuffer(body, fixed, count, at)
        if all((rec[f"n{k}"] == n).all() for k, n in enumerate(lengths)):
            out, k = {}, 0
            for j, (p, c, kind) in enumerate(props):
                v = _widened(rec[f"v{j}"], kind)
                out[p] = v if c is None else (np.full(count, lengths[k], np.int64), v.reshape(-1))
                k += c is not None
            return out, at + count * fixed.itemsize
    return _mixed_records(body, at, count, props, order, element, name, short)


def _mixed_records(body: bytes, at: int, count: int, props: list, order: str, element: str, name: str,
                   short: InputFormatError) -> tuple:
    """:func:`_binary_records` of records whose lists differ in length (triangles and quads): one pass over the
    records finds where each property of each starts (a record's list counts place the next record), reading
    only the counts; then every property is gathered from those places at once.  ``(values, end)``."""
    layout = []  # per property: count size (0: a scalar), count reader, item size
    for _, c, kind in props:
        csize = np.dtype(c).itemsize if c is not None else 0
        signed = c is not None and c[0] == "i"
        layout.append((csize, signed, np.dtype(kind).itemsize))
    big = "big" if order == ">" else "little"
    starts = [array("q") for _ in props]  # where each record's value(s) of a property start (8 bytes an entry,
    lengths = [array("q") for _ in props]  # not a Python int object each)
    pos, end = at, len(body)
    for _ in range(count):
        for j, (csize, signed, isize) in enumerate(layout):
            n = 1
            if csize:
                if pos + csize > end:
                    raise short
                n = int.from_bytes(body[pos: pos + csize], big, signed=signed)
                if n < 0:
                    raise InputFormatError(f"{name}: a PLY {element} list of negative length")
                pos += csize
                lengths[j].append(n)
            starts[j].append(pos)
            pos += n * isize
        if pos > end:
            raise short
    raw = np.frombuffer(body, np.uint8)
    out = {}
    for j, (p, c, kind) in enumerate(props):
        isize = layout[j][2]
        first = np.frombuffer(starts[j], np.int64)
        n = np.frombuffer(lengths[j], np.int64) if c is not None else np.ones(count, np.int64)
        item = np.repeat(first, n) + isize * (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n))
        data = raw[item[:, None] + np.arange(isize)].reshape(-1).view(order + kind)
        v = _widened(data, kind)
        out[p] = v if c is None else (n, v)
    return out, pos


def _widened(values: np.ndarray, kind: str) -> np.ndarray:
    """Binary values of numpy type ``kind`` as float64 or int64 (a signalling NaN made quiet without numpy's
    RuntimeWarning: refused later, as every NaN coordinate is, or read past)."""
    with np.errstate(invalid="ignore"):
        return values.astype(np.float64 if kind[0] == "f" else np.int64)


def _record_dtype(props: list, lengths: list, order: str) -> np.dtype:
    """The packed structured dtype of a record whose lists have ``lengths``: property j's values in field
    ``v{j}``, list k's count in ``n{k}`` (not the properties' names: a header may name two alike, or one
    ``n0``; a name read twice is the last one's, as in an ASCII file)."""
    fields, k = [], 0
    for j, (_, c, kind) in enumerate(props):
        if c is not None:
            fields.append((f"n{k}", order + c))
            fields.append((f"v{j}", order + kind, (lengths[k],)))
            k += 1
        else:
            fields.append((f"v{j}", order + kind))
    return np.dtype(fields)


def _mesh(values: list, elements: list, name: str, max_faces: int) -> tuple:
    """``(positions (n, 3) float64, triangles (m, 3) int64, {element: values} (the first of each name),
    polygon corners)`` of the parsed elements: the last is None, or ``(corners (t, 3) int64, polygon (t,)
    int64)`` -- where in the face list's items each of the first t triangles' corners is, and the face it
    was fanned from (:func:`_fan_corners`); the strips' triangles follow them."""
    found = {}
    for (element, _, _), v in zip(elements, values):
        found.setdefault(element, v)
    vertex = found.get("vertex", {})
    if not all(axis in vertex for axis in "xyz"):
        raise InputFormatError(f"{name}: its PLY vertex element has no x, y and z properties")
    positions = np.stack([np.asarray(vertex[axis], np.float64) for axis in "xyz"], axis=1)
    polygons = next((found["face"][p] for p in FACE_LISTS if p in found.get("face", {})), None)
    strips = found.get("tristrips", {}).get("vertex_indices")
    if polygons is None and strips is None:
        raise InputFormatError(f"{name}: its PLY face element has no vertex_indices list")
    parts, fans = [], None
    if polygons is not None:
        fans = _fan_corners(polygons[0], name, max_faces)
        parts.append(polygons[1].astype(np.int64)[fans[0]])
    if strips is not None:
        parts.append(_strips(*strips))
    faces = np.concatenate(parts)
    if len(faces) > max_faces:
        raise InputFormatError(f"{name}: more than {max_faces:,} triangles (the encoder's limit)")
    return positions, faces, found, fans


def _fan_corners(lengths: np.ndarray, name: str, max_faces: int) -> tuple:
    """``(corners (t, 3) int64, polygon (t,) int64)``: polygons of ``lengths`` (p,) corners, their indices
    one after another in a list's items, each fan-triangulated in order -- where in the items each triangle's
    corners are, and which polygon it is of (a polygon of one or two corners: one degenerate triangle,
    dropped and counted later as an OBJ's is)."""
    if (lengths <= 0).any():
        raise InputFormatError(f"{name}: a PLY face of no corners")
    tris = np.maximum(lengths - 2, 1)
    if tris.sum() > max_faces:
        raise InputFormatError(f"{name}: more than {max_faces:,} triangles (the encoder's limit)")
    start = np.cumsum(lengths) - lengths
    poly = np.repeat(np.arange(len(lengths)), tris)
    j = np.arange(len(poly)) - np.repeat(np.cumsum(tris) - tris, tris) + 1  # 1 .. k - 2 within each polygon
    last = lengths[poly] - 1
    first = start[poly]
    return np.stack([first, first + np.minimum(j, last), first + np.minimum(j + 1, last)], axis=1), poly


def _strips(lengths: np.ndarray, items: np.ndarray) -> np.ndarray:
    """(t, 3) int64: the triangles of triangle strips (-1 restarts one; every other triangle turned so that
    all face one way)."""
    out = []
    for strip in np.split(items.astype(np.int64), np.cumsum(lengths)[:-1]):
        for run in np.split(strip, np.flatnonzero(strip < 0)):
            run = run[run >= 0]
            out.extend((run[i], run[i + 1], run[i + 2]) if i % 2 == 0 else (run[i + 1], run[i], run[i + 2])
                       for i in range(len(run) - 2))
    return np.array(out, np.int64).reshape(-1, 3)
