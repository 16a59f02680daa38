"""The YAML loader of config and system files.

YAML 1.2 numbers (``1e-3`` is a float), duplicate keys rejected, aliases expanded under a size cap
(a billion-laughs document is refused in milliseconds, before anything walks or prints it), caps on
the text itself and on the nesting of flow collections.

No sympy and no numba here.
"""
from __future__ import annotations

import re

import yaml

from .values import describe

__all__ = ["MAX_YAML_CHARS", "MAX_YAML_NODES", "MAX_YAML_SCALAR_CHARS", "MAX_YAML_DEPTH", "YAMLLimitError",
           "SafeLoader", "yaml_load", "yaml_error_line"]

# A config or system file is a few kB; 4 MB of text or a million expanded nodes is hostile.
MAX_YAML_CHARS = 4_000_000
MAX_YAML_NODES = 1_000_000
MAX_YAML_SCALAR_CHARS = 20_000_000  # characters of every scalar after alias expansion


class YAMLLimitError(yaml.YAMLError):
    """A YAML document over the size caps (text, expanded nodes or characters)."""

    def __init__(self, problem: str, mark=None):
        self.problem = problem
        self.problem_mark = mark
        super().__init__(problem)


class SafeLoader(yaml.SafeLoader):
    """SafeLoader that reads 1e-2 as a float (YAML 1.2; YAML 1.1 wants 1.0e-2), rejects duplicate keys
    and refuses documents whose aliases expand past MAX_YAML_NODES nodes or MAX_YAML_SCALAR_CHARS
    characters (checked on the node graph, before any Python object is built)."""

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        _check_expansion(node)
        return self.construct_document(node)


SafeLoader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
SafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                   |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


def _construct_mapping(loader, node, deep=False):
    loader.flatten_mapping(node)
    seen = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(None, None, f"a mapping key must be a plain value (got "
                                                    f"{describe(key)})", key_node.start_mark) from None
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {describe(key)} (first at line {seen[key] + 1})", key_node.start_mark)
        seen[key] = key_node.start_mark.line
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


SafeLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _check_expansion(root) -> None:
    """Expanded size of the node graph (aliases share nodes: memoised per node, so the count itself costs
    one visit per distinct node), refused above the caps. Iterative: deep nesting cannot recurse."""
    memo: dict[int, tuple[int, int]] = {}
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if key in memo and not done:
            continue
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [c for pair in node.value for c in pair]
        if not done:
            memo[key] = (-1, -1)  # in progress: a child that meets it is an alias of its own ancestor
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in memo)
            continue
        count, chars = 1, len(node.value) if isinstance(node, yaml.ScalarNode) else 0
        for c in children:
            cc, ch = memo.get(id(c), (1, 0))
            if cc < 0:
                raise YAMLLimitError("recursive alias (a value that contains itself); write the values out",
                                     c.start_mark)
            count += cc
            chars += ch
        if count > MAX_YAML_NODES or chars > MAX_YAML_SCALAR_CHARS:
            raise YAMLLimitError(
                f"the document expands to more than {MAX_YAML_NODES:,} values or {MAX_YAML_SCALAR_CHARS:,} "
                "characters (YAML aliases repeat what they point to: an alias bomb?); write the values out",
                node.start_mark)
        memo[key] = (count, chars)


MAX_YAML_DEPTH = 100  # nesting of flow collections (PyYAML takes seconds to refuse 1000 levels)


def _flow_depth(text: str) -> int:
    """Deepest nesting of [ ] and { } outside quoted scalars (a scan before PyYAML recurses into it)."""
    depth = top = 0
    quote = None
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if quote:
            if c == "\\" and quote == '"':
                i += 1
            elif c == quote:
                quote = None
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or text[i - 1] in " \t\n"):
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif c in "[{":
            depth += 1
            top = max(top, depth)
        elif c in "]}":
            depth -= 1
        i += 1
    return top


def yaml_load(text: str):
    """Parse YAML text of a config or a system file (see `SafeLoader`); YAMLError on bad input."""
    if not isinstance(text, str):
        raise YAMLLimitError(f"expected YAML text (got {type(text).__name__})")
    if len(text) > MAX_YAML_CHARS:
        raise YAMLLimitError(f"the text is {len(text):,} characters long; the limit is {MAX_YAML_CHARS:,}")
    if text.count("[") + text.count("{") > MAX_YAML_DEPTH and _flow_depth(text) > MAX_YAML_DEPTH:
        raise YAMLLimitError(f"the document nests [ ] or {{ }} more than {MAX_YAML_DEPTH} levels deep")
    loader = SafeLoader(text)
    try:
        return loader.get_single_data()
    except RecursionError:
        raise YAMLLimitError("the document is nested too deeply") from None
    finally:
        loader.dispose()


def yaml_error_line(e: yaml.YAMLError) -> str:
    """One line for a YAML error: 'invalid YAML at line L, column C: <problem>'."""
    mark = getattr(e, "problem_mark", None)
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"invalid YAML{where}: {problem}"
