# --- one run at a time on a results folder (Snakemake's own lock is off: see the profile) -----
_LOCK = RunLock(R)


onstart:
    try:
        _LOCK.acquire()
    except FolderError as err:
        sys.exit(f"condor: {err}")


onsuccess:
    _LOCK.release()


onerror:
    _LOCK.release()
