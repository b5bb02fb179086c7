"""The one strict reader (edge.schema) and the one folder fsync (edge.fsutil.fsync_dir)."""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar

import pytest

from edge.errors import ConfigError, RecordingError
from edge.fsutil import fsync_dir
from edge.schema import Label, build, require, show


def _small(n: int) -> str | None:
    return None if n < 10 else f"must be below 10, got {n}"


@dataclass(frozen=True)
class Item:
    LABEL: ClassVar[Label] = Label("name", "item {}")

    name: str
    size: Annotated[int, _small]
    tags: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        require(len(set(self.tags)) == len(self.tags), "tags", "names a tag twice")


@dataclass(frozen=True)
class Doc:
    items: tuple[Item, ...]
    notes: dict[str, float] | None = None


def message(data: object, **kw: object) -> str:
    with pytest.raises(RecordingError) as info:
        build(Doc, data, "d.json", error=RecordingError, **kw)  # type: ignore[arg-type]
    return str(info.value)


def test_a_labelled_table_is_named_by_its_key_once_that_is_read() -> None:
    assert message({"items": [{"size": 1}]}) == "d.json: items[0]: name: missing required key"
    assert message({"items": [{"name": "a", "size": "1"}]}) == \
        "d.json: item a: size: expected a whole number, got string '1'"
    assert message({"items": [{"name": "a", "size": 1, "tags": ["x", "x"]}]}) == \
        "d.json: item a: tags: names a tag twice"


def test_an_annotated_check_runs_before_the_label_takes_the_value() -> None:
    assert message({"items": [{"name": "a", "size": 12}]}) == "d.json: item a: size: must be below 10, got 12"


def test_dict_values_are_converted_and_named_by_their_key() -> None:
    doc = build(Doc, {"items": [], "notes": {"x": 1}}, "d.json")
    assert doc.notes == {"x": 1.0}
    assert message({"items": [], "notes": {"x": "1"}}) == \
        "d.json: notes.x: expected a number, got string '1'"
    assert message({"items": [], "notes": [1]}, table="an object") == \
        "d.json: notes: expected an object, got a list of 1"


def test_unknown_keys_are_refused_or_ignored_and_null_means_absent() -> None:
    assert "unknown key" in message({"items": [], "extra": 1})
    doc = build(Doc, {"items": [], "extra": 1, "notes": None}, "d.json", unknown_keys="ignore")
    assert doc == Doc(())


def test_show_escapes_what_is_not_printable_and_cuts_long_text() -> None:
    assert show("frames/a b.png") == "frames/a b.png"
    assert show("a\nb") == "'a\\nb'" and show("a\x1bb") == "'a\\x1bb'"
    assert show("x" * 50, 10) == "x" * 9 + "…"
    with pytest.raises(ConfigError) as info:
        build(Doc, {"items": [], "a\nb": 1}, "c.toml")
    assert str(info.value).startswith("c.toml: 'a\\nb': unknown key")


def test_fsync_dir_syncs_a_folder_and_raises_when_it_cannot_be_opened(tmp_path: Path) -> None:
    fsync_dir(tmp_path)
    with pytest.raises(OSError):
        fsync_dir(tmp_path / "missing")


@pytest.mark.parametrize("code, raises", [(errno.EINVAL, False), (errno.ENOTSUP, False), (errno.EIO, True)])
def test_fsync_dir_passes_over_file_systems_that_cannot_sync_a_folder_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int, raises: bool) -> None:
    def refuse(fd: int) -> None:
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(os, "fsync", refuse)  # the OS's answer, as such a file system gives it
    if raises:
        with pytest.raises(OSError):
            fsync_dir(tmp_path)
    else:
        fsync_dir(tmp_path)
