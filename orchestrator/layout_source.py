"""Reading a layout YAML with the file and line of every value, so errors can name them.

The loader builds plain dicts and lists (subclasses :class:`LocDict`,
:class:`LocList`) that remember where each key and item came from. A derived
layout names its ``base`` file; its own content is applied as a JSON Merge
Patch (RFC 7396: mappings merge key by key, ``null`` deletes a key, anything
else replaces, lists included), then its ``set`` block and finally the
caller's overrides, both as dotted keys::

    base: ../ewl.yaml
    set:
      path.unwind.eccentricity.C: [0.8 mm, 0.3 mm]
      experiment.duration: 20 s

Dotted keys address mapping keys by name and list items by index or, for a
list of named mappings (``path``), by ``name``: ``path.unwind.radius``. A key
whose first part names a path element is taken as under ``path``
(``unwind.radius`` = ``path.unwind.radius``).
"""
import pickle
from dataclasses import dataclass
from pathlib import Path

import yaml


@dataclass(frozen=True)
class Location:
    """Where a value came from: a file line (1-based) or a command-line override."""
    file: str
    line: int = 0
    origin: str = ""  # e.g. "--set experiment.duration=30 s"; empty for a file line

    def __str__(self):
        if self.origin:
            return f"{self.file}: {self.origin}" if self.file else self.origin
        return f"{self.file}:{self.line}" if self.line else self.file


@dataclass(frozen=True)
class Issue:
    location: Location
    field: str
    reason: str

    def __str__(self):
        return f"{self.location}: {self.field}: {self.reason}" if self.field else f"{self.location}: {self.reason}"


class LayoutError(ValueError):
    """An invalid layout. ``issues``: list of :class:`Issue`; the message has one
    ``file:line: field: reason`` line per issue."""

    def __init__(self, issues):
        if isinstance(issues, Issue):
            issues = [issues]
        self.issues = list(issues)
        super().__init__("\n".join(str(i) for i in self.issues))

    @property
    def first(self):
        return self.issues[0] if self.issues else None


class LocDict(dict):
    """A mapping that remembers its own location and each key's."""

    def __init__(self, *args, loc=None, **kw):
        super().__init__(*args, **kw)
        self.loc = loc
        self.key_locs = {}


class LocList(list):
    """A list that remembers its own location and each item's."""

    def __init__(self, *args, loc=None):
        super().__init__(*args)
        self.loc = loc
        self.item_locs = [loc] * len(self)


# ---- loading ------------------------------------------------------------------------------
def _loc(path, node):
    return Location(str(path), node.start_mark.line + 1)


_PARSED = {}   # (resolved path, mtime_ns, size) -> located data, as parsed


def load_yaml(path, text=None):
    """The located data of one YAML file (no ``base`` handling). Raises LayoutError.

    A file is parsed once per version (path, modification time, size) and handed
    out as a copy: a diagnosis or a sweep builds hundreds of variants on one base
    layout, and parsing it was a tenth of their wall time."""
    path = Path(path)
    if text is None:
        try:
            st = path.stat()
            key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
        except OSError:
            key = None
        if key is not None and key in _PARSED:
            return pickle.loads(_PARSED[key])
        data = _load_yaml_text(path, None)
        if key is not None:
            if len(_PARSED) > 64:
                _PARSED.clear()
            # kept pickled: a copy by pickle.loads takes a third of copy.deepcopy's time
            _PARSED[key] = pickle.dumps(data, pickle.HIGHEST_PROTOCOL)
        return data
    return _load_yaml_text(path, text)


def _load_yaml_text(path, text):
    if text is None:
        try:
            text = path.read_text()
        except OSError as exc:
            raise LayoutError(Issue(Location(str(path)), "", f"cannot read the layout: {exc.strerror or exc}")) from None
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise LayoutError(Issue(Location(str(path), 1), "", "the file is empty; a layout is a YAML mapping"))
        return _build(loader, node, path)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else 0
        reason = " ".join(str(x) for x in (exc.context, exc.problem) if x)
        raise LayoutError(Issue(Location(str(path), line), "", f"YAML syntax: {reason}")) from None
    except yaml.YAMLError as exc:
        raise LayoutError(Issue(Location(str(path)), "", f"YAML: {exc}")) from None
    finally:
        loader.dispose()


def _build(loader, node, path, prefix=""):
    if isinstance(node, yaml.MappingNode):
        loader.flatten_mapping(node)  # YAML merge keys (<<)
        out = LocDict(loc=_loc(path, node))
        for knode, vnode in node.value:
            key = loader.construct_object(knode, deep=True)
            if not isinstance(key, (str, int, float, bool)) or isinstance(key, bool):
                raise LayoutError(Issue(_loc(path, knode), "", f"mapping keys must be names (got {key!r})"))
            key = str(key)
            if key in out:
                raise LayoutError(Issue(_loc(path, knode), prefix + key,
                                        f"duplicate key (first given on line {out.key_locs[key].line})"))
            out[key] = _build(loader, vnode, path, f"{prefix}{key}.")
            out.key_locs[key] = _loc(path, knode)
        return out
    if isinstance(node, yaml.SequenceNode):
        out = LocList([_build(loader, n, path, f"{prefix}{i}.") for i, n in enumerate(node.value)],
                      loc=_loc(path, node))
        out.item_locs = [_loc(path, n) for n in node.value]
        return out
    return loader.construct_object(node, deep=True)


def with_location(value, loc):
    """``value`` (plain YAML data) as located data, every key and item at ``loc``."""
    if isinstance(value, dict):
        out = LocDict(loc=loc)
        for k, v in value.items():
            out[str(k)] = with_location(v, loc)
            out.key_locs[str(k)] = loc
        return out
    if isinstance(value, list):
        out = LocList([with_location(v, loc) for v in value], loc=loc)
        out.item_locs = [loc] * len(out)
        return out
    return value


def plain(value):
    """Located data as plain dicts and lists."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


# ---- base files and merge patches ------------------------------------------------------
def merge_patch(target, patch):
    """RFC 7396 merge of located ``patch`` onto located ``target`` (new objects; inputs untouched)."""
    if not isinstance(patch, dict):
        return patch
    out = LocDict(loc=patch.loc if getattr(target, "loc", None) is None else target.loc)
    if isinstance(target, dict):
        for k, v in target.items():
            out[k] = v
            out.key_locs[k] = target.key_locs.get(k, target.loc)
    for k, v in patch.items():
        if v is None:
            out.pop(k, None)
            out.key_locs.pop(k, None)
            continue
        out[k] = merge_patch(out.get(k), v)
        out.key_locs[k] = patch.key_locs.get(k, patch.loc)
    return out


def load_located(path, overrides=None, _seen=()):
    """Located layout data of ``path`` with its ``base`` chain, ``set`` block and ``overrides``
    (dotted key -> value; a string value is read as YAML, so ``"[1 mm, 2 mm]"`` is a list)."""
    path = Path(path)
    data = load_yaml(path)
    if not isinstance(data, dict):
        raise LayoutError(Issue(Location(str(path), 1), "", "a layout must be a YAML mapping of sections"))
    resolved = path.resolve()
    if resolved in _seen:
        raise LayoutError(Issue(data.key_locs.get("base", data.loc), "base",
                                f"circular base: {' -> '.join(str(p) for p in (*_seen, resolved))}"))
    sets = data.pop("set", None)
    set_loc = data.key_locs.pop("set", None)
    if "base" in data:
        base = data.pop("base")
        base_loc = data.key_locs.pop("base")
        if not isinstance(base, str) or not base.strip():
            raise LayoutError(Issue(base_loc, "base", "must be the path of a layout file, relative to this file"))
        base_path = (path.parent / base).resolve()
        if not base_path.is_file():
            raise LayoutError(Issue(base_loc, "base", f"no such file: {base_path}"))
        data = merge_patch(load_located(base_path, None, (*_seen, resolved)), data)
    if sets is not None:
        if not isinstance(sets, dict):
            raise LayoutError(Issue(set_loc, "set", "must be a mapping of dotted keys to values"))
        for key, value in sets.items():
            apply_override(data, key, value, sets.key_locs.get(key, set_loc))
    for key, value in (overrides or {}).items():
        loc = Location(str(path), 0, f"--set {key}={value}")
        if isinstance(value, str) and value.strip():
            value = _override_value(value)
        apply_override(data, key, with_location(value, loc), loc)
    return data


_OVERRIDES_READ = {}   # override string -> its YAML value


def _override_value(text):
    """An override's string read as YAML (the string itself if it does not read; validation
    names it). Memoised: a diagnosis loads every variant under its runs' overrides, and
    reading them again was a tenth of its layout loading. The value is shared:
    :func:`with_location` gives every load containers of its own."""
    if text not in _OVERRIDES_READ:
        if len(_OVERRIDES_READ) > 4096:
            _OVERRIDES_READ.clear()
        try:
            _OVERRIDES_READ[text] = yaml.safe_load(text)
        except yaml.YAMLError:
            _OVERRIDES_READ[text] = text
    return _OVERRIDES_READ[text]


# ---- dotted keys ----------------------------------------------------------------------------
def _item_index(seq, part):
    """Index of ``part`` in a list: an integer, or the ``name`` of a named mapping item."""
    if part.lstrip("-").isdigit():
        i = int(part)
        return i if -len(seq) <= i < len(seq) else None
    for i, item in enumerate(seq):
        if isinstance(item, dict) and item.get("name") == part:
            return i
    return None


def split_key(data, key):
    """Parts of a dotted key; a first part naming a path element gets ``path`` in front."""
    parts = [p for p in str(key).split(".")]
    if any(not p for p in parts):
        raise ValueError("empty part in a dotted key")
    if parts[0] not in data and isinstance(data.get("path"), list) and _item_index(data["path"], parts[0]) is not None \
            and not parts[0].lstrip("-").isdigit():
        parts = ["path"] + parts
    return parts


def apply_override(data, key, value, loc):
    """Set dotted ``key`` of located ``data`` to located ``value`` (``None`` deletes)."""
    try:
        parts = split_key(data, key)
    except ValueError as exc:
        raise LayoutError(Issue(loc, str(key), str(exc))) from None
    cur = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[:depth + 1])
        parent = cur
        if isinstance(cur, list):
            i = _item_index(cur, part)
            if i is None:
                names = [it.get("name") for it in cur if isinstance(it, dict) and it.get("name")]
                known = f" (names: {', '.join(names)})" if names else f" (0..{len(cur) - 1})"
                raise LayoutError(Issue(loc, where, f"no item {part!r} in this list{known}"))
            if last:
                if value is None:
                    del cur[i]
                    del cur.item_locs[i]
                else:
                    cur[i] = value
                    cur.item_locs[i] = loc
                return
            cur = cur[i]
        elif isinstance(cur, dict):
            if last:
                if value is None:
                    cur.pop(part, None)
                    cur.key_locs.pop(part, None)
                else:
                    cur[part] = value
                    cur.key_locs[part] = loc
                return
            if part not in cur or cur[part] is None:
                if value is None:
                    return  # deleting under a missing key: nothing to do
                cur[part] = LocDict(loc=loc)
                cur.key_locs[part] = loc
            cur = cur[part]
        else:
            raise LayoutError(Issue(loc, ".".join(parts[:depth]),
                                    f"is a single value ({cur!r}); it has no key {part!r}"))
        if not isinstance(cur, (dict, list)) and not last:
            cur = _expand_shorthand(parent, parts[depth], cur, parts[:depth + 1])


# A single value standing for a mapping: (key, key of the mapping's parent or None) -> field it fills.
SHORTHANDS = {("span", None): "length", ("line_speed", "experiment"): "initial", (None, "tension"): "initial"}


def _expand_shorthand(parent, key, value, parts):
    """Replace a shorthand value (``span: 1 m``) by its mapping (``{length: 1 m}``) so a dotted key
    can reach into it; a value with no shorthand form is left (the next part then fails)."""
    up = parts[-2] if len(parts) >= 2 else None
    field = SHORTHANDS.get((key, None)) or SHORTHANDS.get((key, up)) or \
        (SHORTHANDS.get((None, up)) if len(parts) >= 3 and parts[-3] == "experiment" else None)
    if field is None or not isinstance(parent, dict):
        return value
    loc = parent.key_locs.get(key, parent.loc)
    out = LocDict({field: value}, loc=loc)
    out.key_locs[field] = loc
    parent[key] = out
    return out


# ---- locating a field -------------------------------------------------------------------------
def locate(data, loc_path):
    """(Location, dotted field name) of the value at ``loc_path`` (keys and indices).

    Parts that are not in the data (pydantic's union tags and validator names)
    are skipped; a missing last part (a missing field) gives the location of
    its parent. List items are named by their ``name`` when they have one.
    """
    cur = data
    where = getattr(data, "loc", None)
    names = []
    for part in loc_path:
        if isinstance(cur, list) and isinstance(part, int) and -len(cur) <= part < len(cur):
            item = cur[part]
            where = cur.item_locs[part] if part < len(cur.item_locs) else cur.loc
            label = item.get("name") if isinstance(item, dict) else None
            names.append(label if isinstance(label, str) and label.isidentifier() else str(part))
            cur = item
        elif isinstance(cur, dict) and isinstance(part, str) and part in cur:
            where = cur.key_locs.get(part, cur.loc)
            names.append(part)
            cur = cur[part]
        elif isinstance(part, str) and (part.startswith(("function-", "json-or-python", "tagged-union",
                                                          "lax-or-strict", "chain[", "union[", "nullable[",
                                                          "[key]"))
                                        or not _looks_like_field(part, cur)):
            continue  # a schema tag, not a key
        else:
            names.append(str(part))  # missing: name it, keep the parent's location
            break
    return where or Location(""), ".".join(names)


def _looks_like_field(part, cur):
    """A loc part that is absent from ``cur``: a missing field (True) or a union tag (False)?"""
    from webline.orchestrator.layout_model import UNION_TAGS
    return part not in UNION_TAGS
