"""The bash completion script of the `condor` command line (`condor completion`), generated
from its parser."""

from __future__ import annotations

import argparse


def completion_script(parser: argparse.ArgumentParser) -> str:
    """A bash completion script for `condor`: subcommands, then each one's options (files
    otherwise), generated from `parser` (condor.cli.build_parser) so that it never goes stale."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    cases = []
    for name, child in sub.choices.items():
        options = sorted(o for a in child._actions for o in a.option_strings)
        cases.append(f'        {name}) opts="{" ".join(options)}" ;;')
    commands = " ".join(sub.choices)
    return "\n".join([
        "# bash completion for condor (condor completion)",
        "_condor() {",
        "    local cur=${COMP_WORDS[COMP_CWORD]} opts",
        "    if [ \"$COMP_CWORD\" -eq 1 ]; then",
        f"        COMPREPLY=($(compgen -W \"{commands} --help --version\" -- \"$cur\"))",
        "        return",
        "    fi",
        "    case ${COMP_WORDS[1]} in",
        *cases,
        "        *) opts=\"\" ;;",
        "    esac",
        "    if [[ $cur == -* ]]; then",
        "        COMPREPLY=($(compgen -W \"$opts\" -- \"$cur\"))",
        "    else",
        "        COMPREPLY=($(compgen -f -- \"$cur\"))",
        "    fi",
        "}",
        "complete -o filenames -F _condor condor",
        ""])
