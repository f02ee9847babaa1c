#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for tests and benchmarks of `ibmr run --executor
# slurm` and of Snakemake's cluster mode: munged, slurmctld and slurmd in the foreground-capable
# daemons' plain modes (no systemd), with their key, sockets, state and logs in DIR.
#   scripts/local_slurm.sh start DIR   # prints `export SLURM_CONF=DIR/slurm.conf` once the node is idle
#   scripts/local_slurm.sh stop DIR    # stops the daemons it started (and their jobs)
# Needs root (slurmd runs jobs as their users) and the packages slurm-wlm and munge.
set -euo pipefail
command=${1:-}
dir=${2:-}
[ -n "$command" ] && [ -n "$dir" ] || { echo "usage: $0 start|stop DIR" >&2; exit 2; }

stop() {
  for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
    [ -f "$pidfile" ] || continue
    pid=$(cat "$pidfile")
    kill "$pid" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null || true
    rm -f "$pidfile"
  done
}

if [ "$command" = stop ]; then stop; exit 0; fi
[ "$command" = start ] || { echo "usage: $0 start|stop DIR" >&2; exit 2; }
for program in munged slurmctld slurmd sbatch squeue sinfo; do
  command -v "$program" >/dev/null || { echo "local_slurm: $program is missing (apt install slurm-wlm munge)" >&2; exit 3; }
done
[ "$(id -u)" -eq 0 ] || { echo "local_slurm: needs root (slurmd starts jobs as their users)" >&2; exit 3; }

dir=$(realpath -m "$dir")
mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
chmod 700 "$dir/munge"
# Its own key and socket: a munged the machine may already run is left alone.
head -c 1024 /dev/urandom > "$dir/munge/munge.key"
chmod 400 "$dir/munge/munge.key"
munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
  --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" --seed-file="$dir/munge/seed"

host=$(hostname -s)
memory_mb=$(awk '/MemTotal/ {print int($2 / 1024)}' /proc/meminfo)
port=$((20000 + RANDOM % 20000))
cat > "$dir/slurm.conf" <<CONF
# Written by ibmr's scripts/local_slurm.sh: one node, this machine.
ClusterName=ibmrlocal
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
SlurmctldPort=$port
SlurmdPort=$((port + 1))
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=1000
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=1,bf_interval=1
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName=$host CPUs=$(nproc) RealMemory=$((memory_mb - 1024)) State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$dir/slurm.conf"
slurmctld -D -i > "$dir/slurmctld.out" 2>&1 &
slurmd -D > "$dir/slurmd.out" 2>&1 &
for _ in $(seq 100); do
  if sinfo --noheader --format=%T 2>/dev/null | grep -q idle; then
    echo "export SLURM_CONF=$dir/slurm.conf"
    exit 0
  fi
  sleep 0.2
done
echo "local_slurm: the node did not come up; see $dir/slurmctld.log and $dir/slurmd.log" >&2
stop
exit 1
