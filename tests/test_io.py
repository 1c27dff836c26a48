"""kincal.io: atomic writes that follow the umask, keep a replaced file's mode, and refuse
to clobber inputs."""

from __future__ import annotations

import os
import stat

import pytest

from kincal.errors import KincalError
from kincal.io import atomic_write_bytes, atomic_write_text, check_outputs, write_json


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_new_files_follow_the_umask(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        atomic_write_bytes(tmp_path / "b.png", b"x")
        write_json(tmp_path / "c.json", {"a": 1})
    finally:
        os.umask(old)
    for name in ("a.txt", "b.png", "c.json"):
        assert _mode(tmp_path / name) == mode, name


def test_a_replaced_file_keeps_its_mode(tmp_path):
    p = tmp_path / "shared.yaml"
    p.write_text("old")
    os.chmod(p, 0o640)
    atomic_write_text(p, "new")
    assert p.read_text() == "new" and _mode(p) == 0o640
    assert [f.name for f in tmp_path.iterdir()] == ["shared.yaml"]      # no temporary left


def test_unwritable_output_is_one_line(tmp_path):
    (tmp_path / "dir").mkdir()
    with pytest.raises(KincalError, match="it is a folder"):
        atomic_write_text(tmp_path / "dir", "x")
    (tmp_path / "file").write_text("x")
    with pytest.raises(KincalError, match="cannot write"):
        atomic_write_text(tmp_path / "file" / "x.txt", "x")      # a file where a folder is
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o500)
    try:
        if os.access(ro, os.W_OK):                       # running as root
            pytest.skip("root can write into a read-only folder")
        with pytest.raises(KincalError, match="cannot write"):
            atomic_write_text(ro / "x.txt", "x")
    finally:
        os.chmod(ro, 0o700)


def test_json_is_standard_json(tmp_path):
    import json

    write_json(tmp_path / "a.json", {"x": float("nan"), "y": [1.0, float("inf")]})
    text = (tmp_path / "a.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"x": None, "y": [1.0, None]}


def test_check_outputs_refuses_clobbering_an_input(tmp_path):
    data = tmp_path / "train.csv"
    data.write_text("x")
    with pytest.raises(KincalError, match=r"option -o: .* is also the input of --data"):
        check_outputs({"-o": str(data)}, {"--data": [str(data)]})
    # the same file by another spelling
    other = tmp_path / "sub" / ".." / "train.csv"
    (tmp_path / "sub").mkdir()
    with pytest.raises(KincalError, match="--json"):
        check_outputs({"--json": str(other)}, {"--data": [str(data)]})
    with pytest.raises(KincalError, match="name the same file"):
        check_outputs({"-o": str(tmp_path / "a"), "--report": str(tmp_path / "a")}, {})
    with pytest.raises(KincalError, match="is a folder"):
        check_outputs({"-o": str(tmp_path)}, {})
    check_outputs({"-o": str(tmp_path / "new.yaml"), "--json": "-"}, {"--data": [str(data)]})


def test_one_reader_of_text_inputs_one_line_each(tmp_path):
    """kincal.io.read_text: the same one-line errors for every text input (robot files,
    URDF, UR calibration, measurement, socket and setup files), the BOM dropped."""
    from kincal.errors import MeasurementFileError
    from kincal.io import read_text

    f = tmp_path / "a.csv"
    f.write_bytes(b"\xef\xbb\xbfx_mm\n1\n")
    assert read_text(f) == "x_mm\n1\n"
    f.write_bytes(b"x\n\xff\n")
    with pytest.raises(MeasurementFileError, match=r"a.csv: not a UTF-8 text file \(byte 2\)"):
        read_text(f, "measurement file", MeasurementFileError)
    with pytest.raises(KincalError, match="no such setup file"):
        read_text(tmp_path / "none.yaml", "setup file")
    with pytest.raises(KincalError, match="is a folder, not a robot file"):
        read_text(tmp_path, "robot file")
