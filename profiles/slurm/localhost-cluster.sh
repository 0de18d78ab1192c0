#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, from Debian's packages, to try profiles/slurm
# (and for tests/test_slurm_cluster.py). Run as root (or with sudo):
#
#   profiles/slurm/localhost-cluster.sh install   # apt-get install slurm-wlm munge (Debian/Ubuntu)
#   profiles/slurm/localhost-cluster.sh start     # munged, slurmctld, slurmd; waits for the node
#   profiles/slurm/localhost-cluster.sh status    # sinfo + squeue
#   profiles/slurm/localhost-cluster.sh stop      # ends the daemons this script started
#
# No accounting database: snakemake-executor-plugin-slurm asks `sacct` for job states by default,
# and falls back to `squeue` when sacct is absent or when told so (--slurm-status-command squeue,
# which it honours when the cluster keeps finished jobs for at least 120 s, MinJobAge). This
# cluster keeps them an hour (MinJobAge=3600), so slurmdbd and MariaDB are not needed.
#
# The node is declared with the resources profiles/slurm asks of its biggest job (train: 8 CPUs,
# 64 GB, one GPU), whatever this machine has (SlurmdParameters=config_overrides): the jobs then
# run as they would on a real cluster, only slower. The GPU is a name (File=/dev/null), not a
# device: torch on a machine without one trains on the CPU.
#
# Everything lives under $CONDOR_SLURM_DIR (default /tmp/condor-slurm): config, state, logs.
set -euo pipefail

DIR=${CONDOR_SLURM_DIR:-/tmp/condor-slurm}
HOST=$(hostname -s)
CPUS=${CONDOR_SLURM_CPUS:-8}
MEM_MB=${CONDOR_SLURM_MEM_MB:-64000}
CONF=/etc/slurm/slurm.conf   # where sbatch, squeue and scontrol look (Debian's SLURM_CONF)

die() { echo "localhost-cluster: $*" >&2; exit 1; }

need_root() {
    [[ $(id -u) == 0 ]] || die "run as root (sudo $0 $1): slurmd and munged start as root"
}

install_packages() {
    need_root install
    command -v apt-get >/dev/null || die "no apt-get: install SLURM (slurmctld, slurmd, munge) with your system's packages"
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends slurm-wlm munge
}

write_config() {
    mkdir -p "$DIR"/{state,spool,log}
    # A config this script did not write is someone's cluster: never overwrite it.
    if [[ -e $CONF ]] && ! grep -q "^# written by condor localhost-cluster.sh" "$CONF"; then
        die "$CONF exists and was not written by this script; stop (it belongs to another cluster)"
    fi
    # written beside and moved into place: a reader (sinfo) never sees half a file
    cat > "$CONF.new" <<EOF
# written by condor localhost-cluster.sh: a single-node cluster on $HOST
ClusterName=condor-local
SlurmctldHost=$HOST
SlurmUser=root
SlurmctldPort=6817
SlurmdPort=6818
AuthType=auth/munge
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
# containers and CI machines: no cgroup or systemd needed
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
MpiDefault=none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SlurmdParameters=config_overrides
ReturnToService=2
# finished jobs stay visible to squeue for an hour (the executor's status queries)
MinJobAge=3600
# a job past its time limit is killed at once (no grace minute)
OverTimeLimit=0
KillWait=5
SchedulerParameters=sched_interval=2
SchedulerType=sched/backfill
GresTypes=gpu
NodeName=$HOST CPUs=$CPUS RealMemory=$MEM_MB Gres=gpu:1 State=UNKNOWN
PartitionName=debug Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
# a second partition on the same node: a site's partition named with slurm_partition
PartitionName=compute Nodes=$HOST MaxTime=INFINITE State=UP
EOF
    cat > /etc/slurm/gres.conf.new <<EOF
# written by condor localhost-cluster.sh
NodeName=$HOST Name=gpu Count=1 File=/dev/null
EOF
}

# The config just written (.new) is the one in place: nothing to change.
config_unchanged() {
    cmp -s "$CONF.new" "$CONF" && cmp -s /etc/slurm/gres.conf.new /etc/slurm/gres.conf
}

install_config() {
    mv "$CONF.new" "$CONF"
    mv /etc/slurm/gres.conf.new /etc/slurm/gres.conf
}

node_up() {
    case $(sinfo -h -n "$HOST" -o %T 2>/dev/null || true) in
        idle|mixed|allocated) return 0 ;;
        *) return 1 ;;
    esac
}

running() { [[ -s $1 ]] && kill -0 "$(cat "$1")" 2>/dev/null; }

start() {
    need_root start
    for cmd in munged slurmctld slurmd sbatch squeue; do
        command -v "$cmd" >/dev/null || die "$cmd not found: run '$0 install' first"
    done
    # one start at a time: two test workers (pytest-xdist) may both find the cluster down. The
    # daemons are started with the lock's descriptor closed (9>&-), or they would hold it forever.
    exec 9>/run/condor-localhost-cluster.lock
    flock 9
    write_config
    # Already up with this config (another worker started it, or an earlier session): leave it
    # alone. Rewriting the config or reconfiguring under a running workflow disturbs its jobs.
    if config_unchanged && running "$DIR/slurmctld.pid" && running "$DIR/slurmd.pid" && node_up; then
        rm -f "$CONF.new" /etc/slurm/gres.conf.new
        sinfo
        return 0
    fi
    install_config
    # munge: the key comes with the package; its socket directory may not exist in a container
    install -d -o munge -g munge -m 0755 /run/munge
    [[ -s /etc/munge/munge.key ]] || die "/etc/munge/munge.key missing: reinstall munge or create it with mungekey"
    if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
        # a munged started meanwhile by someone else holds the socket: this one then fails, and
        # the check below is what decides
        runuser -u munge -- /usr/sbin/munged 9>&- || echo "localhost-cluster: munged did not start; checking for a running one" >&2
        sleep 1
        munge -n | unmunge >/dev/null || die "munged is not running or does not authenticate (see /var/log/munge/munged.log)"
    fi
    if running "$DIR/slurmctld.pid"; then
        scontrol reconfigure 9>&- || die "slurmctld runs but does not answer: see $DIR/log/slurmctld.log"
    else
        slurmctld 9>&- || die "slurmctld did not start: see $DIR/log/slurmctld.log"
    fi
    running "$DIR/slurmd.pid" || slurmd 9>&- || die "slurmd did not start: see $DIR/log/slurmd.log"
    for _ in $(seq 60); do
        state=$(sinfo -h -n "$HOST" -o %T 2>/dev/null || true)
        case $state in
            idle|mixed|allocated) sinfo; return 0 ;;
            # a node drained by an earlier run (state is kept in $DIR/state): bring it back
            drain*|drng|inval|down*) scontrol update NodeName="$HOST" State=RESUME 2>/dev/null || true ;;
        esac
        sleep 1
    done
    sinfo >&2 || true
    tail -n 20 "$DIR/log/slurmctld.log" "$DIR/log/slurmd.log" >&2 || true
    die "node $HOST not idle after 60 s (logs above)"
}

stop() {
    for daemon in slurmd slurmctld; do
        if running "$DIR/$daemon.pid"; then kill "$(cat "$DIR/$daemon.pid")"; fi
    done
}

status() {
    sinfo && squeue
}

case "${1:-}" in
    install) install_packages ;;
    start) start ;;
    stop) stop ;;
    status) status ;;
    *) die "usage: $0 install|start|stop|status" ;;
esac
