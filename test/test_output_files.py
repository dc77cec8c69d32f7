"""Output files (``rheo_ros.io.files``): whole or not at all, never through a planted link."""

from __future__ import annotations

import os
import stat

import pytest

from rheo_ros.io.files import write_text_atomic


def test_a_file_is_written_whole_with_the_usual_mode(tmp_path):
    path = write_text_atomic(tmp_path / "out.json", "{}\n")
    assert path.read_text() == "{}\n" and os.listdir(tmp_path) == ["out.json"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_a_symlink_at_the_path_is_replaced_not_followed(tmp_path):
    victim = tmp_path / "victim"
    victim.write_text("mine")
    (tmp_path / "out.html").symlink_to(victim)
    write_text_atomic(tmp_path / "out.html", "<html></html>")
    assert victim.read_text() == "mine"
    assert not (tmp_path / "out.html").is_symlink() and (tmp_path / "out.html").read_text() == "<html></html>"


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    (tmp_path / "out.json").write_text("old")
    with pytest.raises(UnicodeEncodeError):
        write_text_atomic(tmp_path / "out.json", "\ud800")   # a lone surrogate: not UTF-8
    assert (tmp_path / "out.json").read_text() == "old" and os.listdir(tmp_path) == ["out.json"]
