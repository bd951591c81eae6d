"""`expand_prompt` (also `byc prompt`): list prompts and macros, or print one fully expanded.

The text printed is exactly what an agent sends (the same expansion function), unless --comment
asks for macro boundary markers. Exit codes: 0 ok, 1 macro error (cycle, unknown macro, too deep),
3 unknown name, 4 prompt file missing or invalid; 2 is argparse's usage error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from by_your_command.config_files.located_yaml import ConfigError
from by_your_command.prompts.expansion import Annotation, MacroError
from by_your_command.prompts.library import PromptLibrary, load_prompt_library

EXIT_OK = 0
EXIT_MACRO_ERROR = 1
EXIT_UNKNOWN_NAME = 3
EXIT_BAD_FILE = 4
PREVIEW_CHARS = 60


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", nargs="?", help="a prompt id or a macro name to expand")
    parser.add_argument("-l", "--list", action="store_true", help="list prompts, macros and user prefixes")
    parser.add_argument("-o", "--output", metavar="FILE", help="write the expanded text to FILE")
    parser.add_argument(
        "-c", "--comment", action="store_true", help="mark macro boundaries inline (<!-- begin macro: X -->)"
    )
    parser.add_argument(
        "--indent", type=int, default=2, metavar="N", help="spaces per nesting level of --comment markers"
    )
    parser.add_argument(
        "-p", "--prompts-file", metavar="PATH", help="prompts.yaml to use (default: the installed one)"
    )


def _preview(text: str) -> str:
    line = " ".join(text.split())
    return line if len(line) <= PREVIEW_CHARS else line[: PREVIEW_CHARS - 3] + "..."


def listing(library: PromptLibrary) -> str:
    lines = [f"# {library.source}", "prompts:"]
    width = max(len(name) for name in [*library.prompts, *library.macros, *library.user_prefixes])
    default = library.selection.default
    for prompt in library.prompts.values():
        mark = " (default)" if prompt.id == default else ""
        lines.append(f"  {prompt.id:<{width}}  {prompt.name}{mark}: {_preview(prompt.description)}")
    lines.append("macros:")
    for name in sorted(library.macros):
        origin = "[commands.yaml] " if name in library.generated_macros else ""
        lines.append(f"  {name:<{width}}  {origin}{_preview(library.macros[name])}")
    if library.user_prefixes:
        lines.append("user prompt prefixes:")
        for prefix in library.user_prefixes.values():
            lines.append(f"  {prefix.id:<{width}}  {_preview(prefix.prefix)!s}")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    def fail(code: int, message: str) -> int:
        print(f"expand_prompt: {message}", file=sys.stderr)
        return code

    if args.indent < 0:
        return fail(2, f"--indent must be >= 0, got {args.indent}")
    if not args.list and not args.name:
        return fail(2, "give a prompt or macro NAME, or --list")
    try:
        library = load_prompt_library(args.prompts_file, verify=False)
    except (ConfigError, FileNotFoundError) as error:
        return fail(EXIT_BAD_FILE, str(error))
    if args.list:
        text = listing(library)
    else:
        annotation = Annotation(args.indent) if args.comment else None
        try:
            text = library.expand_name(args.name, annotation) + "\n"
        except KeyError:
            return fail(EXIT_UNKNOWN_NAME, f"unknown name {args.name!r}: not a prompt or macro (see --list)")
        except MacroError as error:
            return fail(EXIT_MACRO_ERROR, f"{args.name}: {error}")
    if args.output:
        try:
            Path(args.output).write_text(text, encoding="utf-8")
        except OSError as error:
            return fail(EXIT_BAD_FILE, f"cannot write {args.output}: {error.strerror or error}")
        print(f"wrote {args.name or 'listing'} to {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="expand_prompt", description=__doc__.splitlines()[0] if __doc__ else ""
    )
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
