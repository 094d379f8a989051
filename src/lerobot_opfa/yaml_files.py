"""Reading the YAML files users write (joint maps, camera calibrations, hand specs): a key given twice is
an error, not PyYAML's silent "last one wins" (a joint map's duplicated entry halved a joint in every
frame), and a syntax error is one line with its place and cause (a tab is named as such)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml


class YamlFileError(ValueError):
    """A YAML file that cannot be read as written; the message names the file, the line and the fix."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that names a key twice."""

    def construct_mapping(self, node, deep=False):
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key '{key}' given twice (lines {seen[key]} and {line}); keep one",
                    key_node.start_mark,
                )
            seen[key] = line
        return super().construct_mapping(node, deep)


def read_yaml(path: Path | str, what: str = "file") -> Any:
    """The content of the YAML file `path`; any problem (missing, not YAML, a key twice) is a
    `YamlFileError` of one line naming `what`, the file and the line."""
    path = Path(path)
    if not path.is_file():
        raise YamlFileError(f"{what} {path}: no such file")
    try:
        return yaml.load(path.read_text(), Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        place = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = err.problem or err.context or ""
        if "'\\t'" in problem or "tab" in problem:
            problem = "a tab character; YAML indents with spaces only"
        elif not isinstance(err, yaml.constructor.ConstructorError):
            problem = f"not valid YAML ({problem})"
        raise YamlFileError(f"{what} {path}:{place}: {problem}") from None
    except yaml.YAMLError as err:
        raise YamlFileError(f"{what} {path}: not valid YAML ({' '.join(str(err).split())})") from None
    except UnicodeDecodeError as err:
        raise YamlFileError(f"{what} {path}: not a text file ({err.reason} at byte {err.start})") from None
