# --- one run at a time on a results folder (Snakemake's own lock is off: see the profile) -----
# Taken while the workflow is read, before Snakemake looks at any file: a second run, even
# one started in the same instant, stops here with condor's message, before it could meet a
# file the first run is rewriting. A run that only looks (a dry run, -n; a listing, a graph,
# a lint, a summary) takes none. Released however the run ends.
import atexit
import re

LOOK_ONLY = ("--dry-run", "--dryrun", "--lint", "--list", "--list-rules", "--list-target-rules",
             "--lt", "--summary", "--detailed-summary", "--dag", "--rulegraph", "--filegraph",
             "--d3dag", "--print-compilation", "--list-changes", "--lc", "--list-input-changes",
             "--li", "--list-params-changes", "--lp", "--list-code-changes", "--list-untracked",
             "--lu", "--report", "-l", "-S", "-D")


def looks_only(argv) -> bool:
    """Whether Snakemake's command line `argv` only looks at the folder (LOOK_ONLY; -n, or
    short flags with it such as -pn)."""
    return any(arg.split("=")[0] in LOOK_ONLY or re.fullmatch(r"-[a-zA-Z]*n[a-zA-Z]*", arg)
               for arg in argv)


_LOCK = RunLock(R)
if workflow.is_main_process and not looks_only(sys.argv[1:]):
    try:
        _LOCK.acquire()
    except FolderError as err:
        sys.exit(f"condor: {err}")
    atexit.register(_LOCK.release)


onsuccess:
    _LOCK.release()


onerror:
    _LOCK.release()
