"""The cache folder's listing and clean-up (uplift_common/cache_folder.py, ``uplift cache``): the
entries by kind, those not used for a number of days removed, and nothing else ever touched."""
import json
import os
import time

import pytest

from orchestrator.cli import main
from uplift_common.cache_folder import cache_entries, prune_cache, usage_lines

NOW = time.time()
DAY = 86400.0


def _file(path, size=10, age_days=0.0):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    t = NOW - age_days * DAY
    os.utime(path, (t, t))
    return path


@pytest.fixture
def folder(tmp_path):
    """A cache folder with entries of several kinds and ages, and files that are not entries."""
    c = tmp_path / "cache"
    _file(c / "impedance_gap_0123456789abcdef0123.h5", 1000, age_days=30)
    _file(c / "fit-0123456789abcdef01234567.h5", 200, age_days=2)
    _file(c / "fit-fedcba9876543210fedcba98.h5", 300, age_days=40)
    _file(c / "tf-split-00112233445566778899aabb.h5", 5000, age_days=10)
    _file(c / "dtcheck-00112233445566778899aabb.h5.damaged", 7, age_days=50)
    _file(c / "native" / "uplift-fmu2-0123456789abcdef01234567.so", 400, age_days=60)
    # not entries: left alone whatever their age
    _file(c / "native" / ".uplift-fmu2.lock", 0, age_days=90)
    _file(c / ".fit-aaaa0000bbbb1111.h5.host-123.abc.tmp", 50, age_days=90)     # a write under way
    _file(c / "notes.txt", 5, age_days=90)                                       # the user's own file
    _file(c / "Fit-0123456789abcdef.h5", 5, age_days=90)                         # not the project's naming
    (c / "fit-99999999aaaaaaaa.h5").mkdir()                                      # a folder of an entry's name
    return c


def test_entries_are_listed_by_kind(folder):
    entries = cache_entries(folder)
    kinds = sorted((e.kind, e.bytes) for e in entries)
    assert kinds == [("damaged", 7), ("fit", 200), ("fit", 300), ("impedance_gap", 1000),
                     ("native/uplift-fmu2", 400), ("tf-split", 5000)]
    fit = next(e for e in entries if e.bytes == 300)
    assert fit.last_used == pytest.approx(NOW - 40 * DAY, abs=1)
    lines = usage_lines(entries, now=NOW)
    assert lines[1].split()[:2] == ["tf-split", "1"]                    # the largest kind first
    fit_line = next(line for line in lines if line.startswith("fit "))
    assert fit_line.split()[1] == "2" and fit_line.endswith("40.0 d")    # its least recently used entry
    assert lines[-1].split() == ["total", "6", "6.7", "KiB"]                # 6907 bytes
    assert cache_entries(folder / "absent") == []


def test_a_read_counts_as_a_use(folder):
    # the later of the access and the write time: an entry read yesterday is kept by a pruning of 5 days
    path = folder / "fit-fedcba9876543210fedcba98.h5"
    os.utime(path, (NOW - DAY, NOW - 40 * DAY))
    assert {e.path.name for e in prune_cache(folder, 5, now=NOW)} == {
        "impedance_gap_0123456789abcdef0123.h5", "tf-split-00112233445566778899aabb.h5",
        "dtcheck-00112233445566778899aabb.h5.damaged", "uplift-fmu2-0123456789abcdef01234567.so"}
    assert path.is_file()


def test_prune_removes_only_entries_older_than_the_limit(folder):
    before = set(folder.rglob("*"))
    removed = prune_cache(folder, 35, now=NOW)
    assert sorted(e.path.name for e in removed) == ["dtcheck-00112233445566778899aabb.h5.damaged",
                                                      "fit-fedcba9876543210fedcba98.h5",
                                                      "uplift-fmu2-0123456789abcdef01234567.so"]
    assert before - set(folder.rglob("*")) == {e.path for e in removed}
    # 0 days: every entry, and still nothing else (the user's file, the lock, the temporary, the folder)
    prune_cache(folder, 0, now=NOW)
    assert cache_entries(folder) == []
    left = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))
    assert left == [".fit-aaaa0000bbbb1111.h5.host-123.abc.tmp", "Fit-0123456789abcdef.h5",
                    "fit-99999999aaaaaaaa.h5", "native", "native/.uplift-fmu2.lock", "notes.txt"]
    with pytest.raises(ValueError, match="older_than_days must be >= 0"):
        prune_cache(folder, -1)


def test_every_entry_a_run_writes_is_listed(tmp_path, monkeypatch):
    # a small scene's fit with a cache folder: every file it leaves (the sweep's tables, the fit) is
    # an entry of a known kind, nothing hidden left
    from helpers.scenes import small_reactor, write_scene
    cache = tmp_path / "cache"
    monkeypatch.setenv("UPLIFT_CACHE", str(cache))
    scene = write_scene(tmp_path / "small.toml", small_reactor(motion={"duration_s": 0.5}))
    assert main(["fit", scene, "-o", str(tmp_path / "fit.h5")]) == 0
    entries = cache_entries(cache)
    assert {p for p in cache.rglob("*") if p.is_file()} == {e.path for e in entries}
    assert {"fit", "impedance_gap"} <= {e.kind for e in entries}


def test_the_cache_command_lists_and_prunes(folder, capsys, monkeypatch):
    # `uplift cache` lists the folder's entries by kind; --prune DAYS removes those unused for DAYS days
    # (said on stderr) and lists what is left; --json gives the same as one object; a negative DAYS is
    # bad input (exit 2) and removes nothing
    monkeypatch.setenv("UPLIFT_CACHE", str(folder))
    assert main(["cache"]) == 0
    out = capsys.readouterr().out
    assert f"cache folder {folder}" in out and out.splitlines()[-1].split()[:2] == ["total", "6"]
    assert main(["cache", "--prune", "-1"]) == 2 and len(cache_entries(folder)) == 6
    capsys.readouterr()
    assert main(["cache", "--prune", "35"]) == 0
    captured = capsys.readouterr()
    assert "removed 3 entries (707 bytes) not used for 35 days" in captured.err
    assert captured.out.splitlines()[-1].split()[:2] == ["total", "3"]
    assert main(["cache", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["folder"] == str(folder) and got["removed"] == 0
    assert got["kinds"] == {"fit": {"entries": 1, "bytes": 200}, "impedance_gap": {"entries": 1, "bytes": 1000},
                            "tf-split": {"entries": 1, "bytes": 5000}}
