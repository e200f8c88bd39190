"""Atomic output files: whole or absent, with a normal file's mode, written through links, never onto devices."""
import os
import stat

import pytest

from xshells.errors import InputError
from xshells.io.export import atomic_write_text


def test_a_finished_file_has_the_mode_open_would_give_it(tmp_path, monkeypatch):
    # mkstemp's 0600 stayed on every output: other users (and a web server) could not read the results
    from xshells.io import export

    atomic_write_text(tmp_path / "b.txt", "x")
    with open(tmp_path / "c.txt", "w") as fh:  # what open() gives under this process's umask
        fh.write("x")
    assert stat.S_IMODE(os.stat(tmp_path / "b.txt").st_mode) == stat.S_IMODE(os.stat(tmp_path / "c.txt").st_mode)
    monkeypatch.setattr(export, "_UMASK", 0o027)
    atomic_write_text(tmp_path / "a.txt", "x")
    assert stat.S_IMODE(os.stat(tmp_path / "a.txt").st_mode) == 0o640


def test_a_symbolic_link_is_written_through(tmp_path):
    (tmp_path / "target.json").write_text("old")
    os.symlink(tmp_path / "target.json", tmp_path / "link.json")
    atomic_write_text(tmp_path / "link.json", "new")
    assert os.path.islink(tmp_path / "link.json") and (tmp_path / "target.json").read_text() == "new"


def test_a_device_or_a_folder_is_refused_in_one_line(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)  # not a regular file, like /dev/null: renaming onto it replaced the node
    for path, words in ((fifo, "not a regular file"), (tmp_path, "a folder"), ("", "empty")):
        with pytest.raises(InputError) as err:
            atomic_write_text(path, "x")
        assert words in str(err.value) and "\n" not in str(err.value)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
