#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for running and testing the workflow through the Slurm
# profile (workflow/profiles/slurm) without a real cluster. Debian 12, as root.
#
#   bash workflow/profiles/slurm/local_cluster.sh start    # install (once), configure, start; wait for `sinfo`
#   bash workflow/profiles/slurm/local_cluster.sh status   # daemons and node state
#   bash workflow/profiles/slurm/local_cluster.sh stop     # stop the daemons this script started
#
# start installs Debian's slurm-wlm and munge (apt-get update first; skipped when Slurm is installed), writes
# /etc/slurm/slurm.conf for one node on localhost with this machine's CPUs and memory (never over a
# slurm.conf this script did not write), starts munged, slurmctld and slurmd, and waits until the node is
# idle. Running it again when the cluster is up does nothing but check it.
#
# Job states: no accounting database (no slurmdbd, no MariaDB). The profile asks `squeue` for job states
# (slurm: status-command: squeue); slurmctld keeps finished jobs for MinJobAge (600 s), long enough for
# the executor's status checks. Every finished job is also written to a job-completion log
# (JobCompLoc, default /var/log/slurm/jobcomp.log), which tests read to see which jobs Slurm ran.
# Containers/VMs without cgroup delegation: process tracking by /proc (proctrack/linuxproc), no task
# plugin, no cgroup; daemons and jobs run as root.
set -euo pipefail

MODE="${1:-start}"
CONF_DIR=/etc/slurm
CONF="$CONF_DIR/slurm.conf"
MARKER="# written by hybridfmu workflow/profiles/slurm/local_cluster.sh"
STATE_DIR="${SLURM_LOCAL_STATE_DIR:-/var/lib/hybridfmu-slurm}"
LOG_DIR=/var/log/slurm
JOBCOMP_LOG="$LOG_DIR/jobcomp.log"
RUN_DIR=/run/slurm
WAIT_S="${SLURM_LOCAL_WAIT_S:-120}"
NODE="$(hostname -s)"

say() { echo "[local_cluster] $*"; }
fail() { echo "[local_cluster] ERROR: $*" >&2; exit 1; }

[ "$(id -u)" -eq 0 ] || fail "must run as root (installs packages, starts munged/slurmctld/slurmd)"

pid_alive() {  # pid_alive <pidfile>: the process named in the file runs
    [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null
}

node_state() {
    sinfo --noheader --nodes="$NODE" --format=%T 2>/dev/null | head -n1 | tr -d ' *'
}

install_packages() {
    if command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v sbatch >/dev/null \
        && command -v munged >/dev/null; then
        say "slurm and munge already installed (slurm-client $(dpkg-query -W -f '${Version}' slurm-client 2>/dev/null))"
        return
    fi
    command -v apt-get >/dev/null || fail "apt-get not found: this script installs Slurm from Debian's packages"
    local start=$SECONDS
    say "apt-get update"
    apt-get update -q >/dev/null || fail "apt-get update failed"
    say "installing slurm-wlm and munge (Debian packages)"
    # no daemon is started by the packages' install scripts (no init system in containers; this script
    # starts them itself): policy-rc.d denies it for the duration of the install
    local policy=/usr/sbin/policy-rc.d own_policy=0
    if [ ! -e "$policy" ]; then
        printf '#!/bin/sh\nexit 101\n' >"$policy" && chmod +x "$policy" && own_policy=1
    fi
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
        slurm-wlm slurm-client munge >/dev/null; then
        [ "$own_policy" -eq 1 ] && rm -f "$policy"
        fail "apt-get install slurm-wlm munge failed"
    fi
    [ "$own_policy" -eq 1 ] && rm -f "$policy"
    say "installed slurm-client $(dpkg-query -W -f '${Version}' slurm-client) in $((SECONDS - start)) s"
}

write_config() {
    if [ -e "$CONF" ] && ! grep -qF "$MARKER" "$CONF"; then
        fail "$CONF exists and was not written by this script (a real cluster's config?); not overwriting it"
    fi
    mkdir -p "$CONF_DIR" "$STATE_DIR/slurmctld" "$STATE_DIR/slurmd" "$LOG_DIR" "$RUN_DIR"
    # this machine's CPUs, sockets, cores and memory, as slurmd itself detects them
    local hardware memory
    hardware="$(slurmd -C | head -n1)" || fail "slurmd -C failed"
    hardware="$(echo "$hardware" | sed -E "s/^NodeName=[^ ]+ //; s/ RealMemory=[0-9]+//")"
    memory="$(slurmd -C | sed -nE 's/.*RealMemory=([0-9]+).*/\1/p')"
    # a little memory for the system and the daemons
    memory=$((memory * 95 / 100))
    local new
    new="$(cat <<EOF
$MARKER
ClusterName=localcluster
SlurmctldHost=$NODE(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$JOBCOMP_LOG
MinJobAge=600
DefMemPerCPU=1000
ReturnToService=2
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
StateSaveLocation=$STATE_DIR/slurmctld
SlurmdSpoolDir=$STATE_DIR/slurmd
SlurmctldPidFile=$RUN_DIR/slurmctld.pid
SlurmdPidFile=$RUN_DIR/slurmd.pid
SlurmctldLogFile=$LOG_DIR/slurmctld.log
SlurmdLogFile=$LOG_DIR/slurmd.log
SlurmctldTimeout=30
SlurmdTimeout=60
NodeName=$NODE NodeAddr=127.0.0.1 $hardware RealMemory=$memory State=UNKNOWN
PartitionName=local Nodes=$NODE Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
EOF
)"
    if [ -e "$CONF" ] && [ "$(cat "$CONF")" = "$new" ]; then
        say "$CONF unchanged"
        return 1
    fi
    echo "$new" >"$CONF"
    say "wrote $CONF: $(grep '^NodeName' "$CONF")"
    return 0
}

start_munge() {
    if pid_alive /run/munge/munged.pid; then
        say "munged runs (PID $(cat /run/munge/munged.pid))"
        return
    fi
    mkdir -p /etc/munge /run/munge /var/lib/munge /var/log/munge
    if [ ! -s /etc/munge/munge.key ]; then
        say "creating /etc/munge/munge.key"
        if command -v mungekey >/dev/null; then
            mungekey --create --keyfile=/etc/munge/munge.key
        else
            dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
        fi
    fi
    chown -R munge:munge /etc/munge /run/munge /var/lib/munge /var/log/munge
    chmod 0700 /etc/munge
    chmod 0400 /etc/munge/munge.key
    chmod 0755 /run/munge
    runuser -u munge -- /usr/sbin/munged || fail "munged did not start (see /var/log/munge/munged.log)"
    munge -n | unmunge >/dev/null || fail "munge does not work: munge -n | unmunge failed"
    say "munged started (PID $(cat /run/munge/munged.pid))"
}

start_daemon() {  # start_daemon <name> <pidfile>
    local name=$1 pidfile=$2
    if pid_alive "$pidfile"; then
        say "$name runs (PID $(cat "$pidfile"))"
        return
    fi
    "/usr/sbin/$name" || fail "$name did not start (see $LOG_DIR/$name.log)"
    local waited=0
    until pid_alive "$pidfile"; do
        [ "$waited" -ge 20 ] && fail "$name did not start within 20 s (see $LOG_DIR/$name.log)"
        sleep 0.5
        waited=$((waited + 1))
    done
    say "$name started (PID $(cat "$pidfile"))"
}

stop_daemon() {  # stop_daemon <name> <pidfile>
    local name=$1 pidfile=$2
    if ! pid_alive "$pidfile"; then
        say "$name is not running"
        return
    fi
    local pid
    pid="$(cat "$pidfile")"
    kill "$pid"
    for _ in $(seq 1 40); do
        kill -0 "$pid" 2>/dev/null || { say "$name stopped (PID $pid)"; return; }
        sleep 0.25
    done
    kill -9 "$pid" 2>/dev/null || true
    say "$name killed (PID $pid did not end within 10 s)"
}

wait_idle() {
    local waited=0 state
    while true; do
        state="$(node_state)"
        case "$state" in
            idle|mixed|allocated)
                say "node $NODE is $state: $(sinfo --noheader --format='partition %P, %D node(s), %c CPUs, %m MB' | head -n1)"
                return ;;
            down|drain|drained|draining|fail|failing|invalid*)
                # a node that was down (e.g. the machine restarted) is resumed once
                if [ "$waited" -eq 0 ] || [ "$((waited % 10))" -eq 0 ]; then
                    scontrol update NodeName="$NODE" State=RESUME 2>/dev/null || true
                fi ;;
        esac
        if [ "$waited" -ge "$WAIT_S" ]; then
            sinfo -N -l >&2 || true
            tail -n 20 "$LOG_DIR/slurmctld.log" "$LOG_DIR/slurmd.log" >&2 || true
            fail "node $NODE not idle after $WAIT_S s (state: ${state:-unknown}); see $LOG_DIR/slurmctld.log and slurmd.log"
        fi
        sleep 1
        waited=$((waited + 1))
    done
}

case "$MODE" in
    start)
        start=$SECONDS
        install_packages
        changed=0
        write_config && changed=1
        start_munge
        if [ "$changed" -eq 1 ]; then  # a new config: daemons started with an older one restart
            stop_daemon slurmd "$RUN_DIR/slurmd.pid"
            stop_daemon slurmctld "$RUN_DIR/slurmctld.pid"
        fi
        start_daemon slurmctld "$RUN_DIR/slurmctld.pid"
        start_daemon slurmd "$RUN_DIR/slurmd.pid"
        wait_idle
        say "cluster up in $((SECONDS - start)) s; job-completion log: $JOBCOMP_LOG"
        ;;
    stop)
        stop_daemon slurmd "$RUN_DIR/slurmd.pid"
        stop_daemon slurmctld "$RUN_DIR/slurmctld.pid"
        stop_daemon munged /run/munge/munged.pid
        ;;
    status)
        for daemon in slurmctld slurmd; do
            if pid_alive "$RUN_DIR/$daemon.pid"; then say "$daemon runs (PID $(cat "$RUN_DIR/$daemon.pid"))"
            else say "$daemon is not running"; fi
        done
        command -v sinfo >/dev/null && sinfo -N -l || true
        ;;
    *)
        fail "unknown mode '$MODE'; expected start, stop or status"
        ;;
esac
