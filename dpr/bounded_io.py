"""Reading what a user hands over with limits: files of a bounded size, yaml without duplicate keys or alias bombs,
and zip members whose declared and actual sizes are checked before and while they are read.

Every yaml file dpr reads goes through :func:`load_yaml` (settings, presets, hyperparameters, model cards, run
records), and every model zip member through :func:`read_zip_member`: a ``--config /dev/zero``, a "billion laughs"
inside a valid key, or a member that inflates to gigabytes ends in an error naming the file, never in a machine out
of memory. The bounds are in :mod:`dpr.limits`.
"""

from __future__ import annotations

import os
import stat
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from dpr.checks import ParameterError
from dpr.limits import MAX_SETTINGS_BYTES, MAX_YAML_ALIASES, MAX_YAML_NODES, MiB

__all__ = ["YamlRefused", "load_yaml", "load_yaml_text", "read_bounded", "read_zip_member", "stream_zip_member"]

MERGE_TAG = "tag:yaml.org,2002:merge"
CHUNK = 1 * MiB


class YamlRefused(ParameterError, yaml.YAMLError):
    """A yaml file refused for its size or structure (a duplicate key, too many aliases): a ParameterError about
    the parameter that named the file, and a yaml error for the callers that set damaged records aside."""


def _size(value: int) -> str:
    return f"{value / MiB:.1f} MiB" if value >= MiB else f"{value} bytes"


def read_bounded(path: str | Path, limit: int, name: str = "path") -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them: a device, a fifo or a folder, or a file
    over the limit, is a :class:`ParameterError` about ``name`` before anything is read (OSError as ``open``'s)."""
    path = Path(path)
    descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a fifo must not block the open
    with os.fdopen(descriptor, "rb") as file:
        mode = os.fstat(file.fileno()).st_mode
        if not stat.S_ISREG(mode):
            raise ParameterError(name, f"{path} is not a regular file")
        size = os.fstat(file.fileno()).st_size
        data = file.read(limit + 1) if size <= limit else b""
    if size > limit or len(data) > limit:
        raise ParameterError(name, f"{path} holds {_size(max(size, len(data)))}, more than {_size(limit)}")
    return data


class BoundedLoader(yaml.SafeLoader):
    """yaml's safe loader that refuses a duplicate key in a mapping (yaml would keep the last silently), more than
    :data:`MAX_YAML_ALIASES` aliases, an alias to itself, and a document of more than :data:`MAX_YAML_NODES` nodes
    once its aliases are expanded (what a consumer of the data would walk)."""

    source = "<yaml>"
    parameter = "config"

    def _refuse(self, mark, problem: str):
        line = f", line {mark.line + 1}" if mark is not None else ""
        return YamlRefused(self.parameter, f"{self.source}{line}: {problem}")

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self._aliases = getattr(self, "_aliases", 0) + 1
            if self._aliases > MAX_YAML_ALIASES:
                raise self._refuse(self.peek_event().start_mark, f"more than {MAX_YAML_ALIASES} aliases (*name)")
        return super().compose_node(parent, index)

    def compose_document(self):
        node = super().compose_document()
        # without aliases the tree is what the file spelt out, bounded by the file's size
        if getattr(self, "_aliases", 0) and _expanded_nodes(node, MAX_YAML_NODES, self._refuse) > MAX_YAML_NODES:
            raise self._refuse(None, f"expands to more than {MAX_YAML_NODES} values (its aliases repeat too much)")
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == MERGE_TAG:
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node.start_mark)
                except TypeError:  # an unhashable key: yaml's own error follows
                    continue
                if first is not key_node.start_mark:
                    raise self._refuse(
                        key_node.start_mark,
                        f"key {key!r} appears twice in one mapping (first on line {first.line + 1})",
                    )
        return super().construct_mapping(node, deep)


def _children(node) -> Iterator:
    if isinstance(node, yaml.SequenceNode):
        yield from node.value
    elif isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            yield key
            yield value


def _expanded_nodes(root, limit: int, refuse) -> int:
    """Nodes of the tree ``root`` (a composed yaml graph, whose aliases are shared nodes) once its aliases are
    expanded, counted up to just over ``limit``; an alias to a node that holds it is refused."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def size(node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in open_nodes:
            raise refuse(node.start_mark, "an alias refers to a node that holds it (a recursive structure)")
        open_nodes.add(key)
        total = 1
        for child in _children(node):
            total = min(total + size(child), limit + 1)
        open_nodes.discard(key)
        sizes[key] = total
        return total

    return size(root)


def load_yaml_text(text: str | bytes, source: str = "<yaml>", parameter: str = "config") -> Any:
    """The yaml document ``text`` (from ``source``, named in errors) through :class:`BoundedLoader`; a refusal is a
    :class:`YamlRefused` about ``parameter``, a syntax error yaml's own :class:`yaml.YAMLError`."""
    loader = BoundedLoader(text)
    loader.source, loader.parameter = source, parameter
    try:
        return loader.get_single_data()
    except RecursionError:
        raise YamlRefused(parameter, f"{source}: nested too deeply") from None
    finally:
        loader.dispose()


def load_yaml(
    path: str | Path, parameter: str = "config", limit: int = MAX_SETTINGS_BYTES, *, missing: Any = ...
) -> Any:
    """The yaml file ``path``, at most ``limit`` bytes (:func:`read_bounded`), through :func:`load_yaml_text`.
    ``missing``: what a file that does not exist gives (default: FileNotFoundError)."""
    try:
        data = read_bounded(path, limit, parameter)
    except FileNotFoundError:
        if missing is ...:
            raise
        return missing
    except ParameterError as error:
        raise YamlRefused(error.parameter, error.problem) from None
    return load_yaml_text(data, str(path), parameter)


def _zip_refusal(name: str, source: str | Path, member: str, problem: str) -> ParameterError:
    return ParameterError(name, f"{source}: its member {member!r} {problem}")


def stream_zip_member(
    archive: zipfile.ZipFile, member: str, limit: int, source: str | Path, name: str
) -> Iterator[bytes]:
    """The bytes of ``member`` of ``archive`` in chunks, refused (a :class:`ParameterError` about ``name``) when it
    declares more than ``limit`` bytes or inflates to more than it declares; its CRC is checked at the end."""
    info = archive.getinfo(member)
    if info.file_size > limit:
        raise _zip_refusal(name, source, member, f"declares {_size(info.file_size)}, more than {_size(limit)}")
    read = 0
    try:
        with archive.open(info) as file:
            while chunk := file.read(CHUNK):
                read += len(chunk)
                if read > info.file_size:  # zipfile stops at the declared size; kept should that ever change
                    raise _zip_refusal(name, source, member, f"inflates past its declared {_size(info.file_size)}")
                yield chunk
    except zipfile.BadZipFile as error:
        raise _zip_refusal(name, source, member, f"is damaged ({error})") from None
    if read != info.file_size:
        raise _zip_refusal(name, source, member, f"holds {read} bytes, not the {info.file_size} it declares")


def read_zip_member(archive: zipfile.ZipFile, member: str, limit: int, source: str | Path, name: str) -> bytes:
    """``member`` of ``archive`` read whole through :func:`stream_zip_member` (at most ``limit`` bytes)."""
    return b"".join(stream_zip_member(archive, member, limit, source, name))
