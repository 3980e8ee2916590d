"""A key file member the loader does not know is refused by name (exit 2), not read as if understood: a
hand-edited ``"owner_idd"`` (meant to set the owner ID) loaded as a key with the old ID or none, and a member a
later writer adds would be taken by this reader as understood.  A key file's members are those its ``version``
defines (version 1: README, "Keys"); a writer that adds one raises the version, which this reader refuses as
unsupported.  Every key the tool wrote (the conformance keys among them) keeps loading."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pmwm_codec.cli import main
from pmwm_codec.errors import WatermarkKeyError
from pmwm_codec.watermark.key import WatermarkKey

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"


@pytest.fixture
def key():
    return WatermarkKey.generate(rng=np.random.default_rng(9), params={"bits": 4},
                                 reference=(np.arange(64) * 4 % 256).astype(np.uint8).reshape(8, 8), file_id="f-1")


@pytest.mark.parametrize("where, member", [("", "owner_idd"), ("", "expires"), ("reference", "mode")])
@pytest.mark.parametrize("checksum", [True, False])
def test_an_unknown_member_is_refused_naming_it(tmp_path, key, where, member, checksum):
    doc = key.to_json()
    if not checksum:
        del doc["checksum"]
    (doc[where] if where else doc)[member] = "00000000000000ff"
    path = tmp_path / "k.key.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(WatermarkKeyError) as info:
        WatermarkKey.load(path)
    text = str(info.value)
    assert text.startswith(f"{path}: not a valid watermark key") and f'unknown member "{member}"' in text, text
    assert "\n" not in text and key.secret_hex not in text


def test_the_command_line_refuses_it_in_one_line_exit_2(tmp_path, key, capsys):
    doc = {**key.to_json(), "owner_idd": "00000000000000ff"}
    path = tmp_path / "k.key.json"
    path.write_text(json.dumps(doc))
    (tmp_path / "x.pmw").write_bytes(b"")
    assert main(["verify", str(tmp_path / "x.pmw"), "--key", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and 'unknown member "owner_idd"' in err, err


def test_every_key_the_tool_wrote_still_loads(tmp_path, key):
    keys = sorted(CONFORMANCE.glob("*.key.json"))
    assert keys
    for path in keys:
        WatermarkKey.load(path)
    key.owner_id = 0x1234
    key.save(tmp_path / "k.key.json")
    assert WatermarkKey.load(tmp_path / "k.key.json") == key
