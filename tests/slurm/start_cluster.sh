#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for tests/test_slurm.py: Debian's slurm-wlm and
# munge, the daemons started directly (no systemd), a generated slurm.conf (proctrack/linuxproc,
# task/none, select/cons_tres, no accounting) on ports of its own, one partition with a MaxTime.
#
#   tests/slurm/start_cluster.sh STATE_DIR
#
# Prints SLURM_CONF=STATE_DIR/slurm.conf once the node is idle (clients need that variable).
# Exit 3 with the reason on stderr where it cannot (not root, no apt-get, install failed, a
# daemon did not start); tests/slurm/stop_cluster.sh STATE_DIR stops the daemons it started.
set -euo pipefail

state=${1:?usage: start_cluster.sh STATE_DIR}
cannot() { echo "cannot start a Slurm cluster: $*" >&2; exit 3; }

[ "$(id -u)" = 0 ] || cannot "not root (the daemons and apt-get need root)"
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null \
    || ! command -v munged >/dev/null || ! command -v sinfo >/dev/null; then
    command -v apt-get >/dev/null || cannot "slurm-wlm is not installed and there is no apt-get"
    export DEBIAN_FRONTEND=noninteractive
    { apt-get install -y -q slurm-wlm munge >"$state.apt.log" 2>&1 \
        || { apt-get update -q && apt-get install -y -q slurm-wlm munge; } >>"$state.apt.log" 2>&1; } \
        || cannot "apt-get install slurm-wlm munge failed (see $state.apt.log)"
fi

mkdir -p "$state"
state=$(cd "$state" && pwd)

# munge: a key, its socket directory, the daemon (as the munge user, as its package intends)
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
    if [ ! -s /etc/munge/munge.key ]; then
        mungekey --create --keyfile /etc/munge/munge.key || cannot "mungekey failed"
    fi
    chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
    mkdir -p /run/munge /var/lib/munge /var/log/munge
    chown munge:munge /run/munge /var/lib/munge /var/log/munge
    runuser -u munge -- /usr/sbin/munged || cannot "munged did not start"
    for _ in $(seq 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
    munge -n | unmunge >/dev/null 2>&1 || cannot "munge does not answer"
fi

host=$(hostname -s)
node=$(slurmd -C | head -1)   # NodeName=<host> CPUs=... RealMemory=...: this machine as it is
conf=$state/slurm.conf
mkdir -p "$state/ctld" "$state/d"
cat >"$conf" <<CONF
ClusterName=gcnt-test
SlurmctldHost=$host
SlurmctldPort=16817
SlurmdPort=16818
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
StateSaveLocation=$state/ctld
SlurmdSpoolDir=$state/d
SlurmctldPidFile=$state/slurmctld.pid
SlurmdPidFile=$state/slurmd.pid
SlurmctldLogFile=$state/slurmctld.log
SlurmdLogFile=$state/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
KillWait=10
MinJobAge=300
$node State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=30 State=UP
CONF
export SLURM_CONF=$conf

running() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }
running "$state/slurmctld.pid" || slurmctld -f "$conf" || cannot "slurmctld did not start ($state/slurmctld.log)"
running "$state/slurmd.pid" || slurmd -f "$conf" || cannot "slurmd did not start ($state/slurmd.log)"

for _ in $(seq 120); do
    case $(sinfo -h -n "$host" -o %t 2>/dev/null) in
        idle*|mix*|alloc*) echo "SLURM_CONF=$conf"; exit 0 ;;
    esac
    sleep 0.5
done
cannot "the node did not become idle in 60 s ($state/slurmctld.log, $state/slurmd.log)"
