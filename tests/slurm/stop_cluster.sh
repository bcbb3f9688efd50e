#!/usr/bin/env bash
# Stop the slurmctld and slurmd that tests/slurm/start_cluster.sh STATE_DIR started (by their
# pid files; munged is left running, as other programs may use it).
set -u
state=${1:?usage: stop_cluster.sh STATE_DIR}
for d in slurmd slurmctld; do
    pidfile=$state/$d.pid
    if [ -s "$pidfile" ]; then
        pid=$(cat "$pidfile")
        kill "$pid" 2>/dev/null
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    fi
done
exit 0
