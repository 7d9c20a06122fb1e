#!/usr/bin/env bash
# A real single-node SLURM on this machine, for running the pipeline through
# `snakemake --profile workflow/profiles/slurm` here (tests/workflow/test_slurm.py, CI).
#
#   sudo bash scripts/start_slurm.sh        # as root: installs Debian's slurm-wlm and munge if missing,
#                                            # writes /etc/slurm/slurm.conf, starts munged, slurmctld, slurmd
#
# One node (this host, all its cores and 90 % of its memory) in one partition, `helioflow`; no
# accounting database, so snakemake's SLURM executor queries job states with squeue (MinJobAge keeps
# finished jobs visible for 10 minutes). Running it again restarts the daemons with the same config.
# Stop them with: pkill slurmd; pkill slurmctld; pkill munged
set -euo pipefail

if [ "$(id -u)" -ne 0 ]; then
    echo "start_slurm.sh: run as root (it installs packages and starts system daemons)" >&2
    exit 1
fi
if ! command -v slurmctld > /dev/null || ! command -v munged > /dev/null; then
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge
fi

host=$(hostname -s)
cpus=$(nproc)
memory_mb=$(awk '/MemTotal/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)

# munge: the key SLURM's daemons and commands authenticate with
mkdir -p /etc/munge /var/log/munge /var/lib/munge /run/munge
if [ ! -s /etc/munge/munge.key ]; then
    dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key status=none
fi
chown -R munge:munge /etc/munge /var/log/munge /var/lib/munge /run/munge
chmod 0700 /etc/munge /var/log/munge /var/lib/munge
chmod 0400 /etc/munge/munge.key
pkill -x munged || true
sudo_munge() { if command -v runuser > /dev/null; then runuser -u munge -- "$@"; else su -s /bin/sh munge -c "$*"; fi; }
sudo_munge /usr/sbin/munged --force

mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
cat > /etc/slurm/slurm.conf <<EOF
# written by helioflow's scripts/start_slurm.sh: one node, one partition
ClusterName=helioflow
SlurmctldHost=${host}
AuthType=auth/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MinJobAge=600
NodeName=${host} CPUs=${cpus} RealMemory=${memory_mb} State=UNKNOWN
PartitionName=helioflow Nodes=${host} Default=YES MaxTime=INFINITE State=UP
EOF
rm -f /etc/slurm/cgroup.conf   # no cgroups: a container may not let slurmd use them (linuxproc, task/none)

pkill -x slurmd || true
pkill -x slurmctld || true
sleep 1
/usr/sbin/slurmctld -c          # -c: a clean start, no state of an earlier cluster
/usr/sbin/slurmd || { echo "start_slurm.sh: slurmd did not start; see /var/log/slurm/slurmd.log" >&2; exit 1; }
for _ in $(seq 1 30); do
    if sinfo --noheader --format=%T 2>/dev/null | grep -qx "idle"; then
        sinfo
        exit 0
    fi
    sleep 1
done
echo "start_slurm.sh: the node did not become idle in 30 s; see /var/log/slurm/" >&2
sinfo >&2 || true
exit 1
