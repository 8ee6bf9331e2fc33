#!/usr/bin/env bash
# A real single-node SLURM on this machine (Debian/Ubuntu, root, no systemd needed), to run the
# workflow through `snakemake --executor slurm` for real: munged, MariaDB, slurmdbd (job
# accounting, which the executor plugin needs for `sacct`), slurmctld and slurmd, all on
# localhost, with one node that has this machine's CPUs and memory.
#
#   scripts/slurm-local.sh start    install the packages if missing (apt-get), write the
#                                   configuration, start the daemons, wait until the node is
#                                   idle and sacct answers (idempotent: a second start only checks)
#   scripts/slurm-local.sh status   the daemons, the node, the queue
#   scripts/slurm-local.sh stop     cancel the jobs, stop exactly the daemons that start started
#                                   (by recorded PID); a munged or MariaDB that was already
#                                   running before start is left running
#   scripts/slurm-local.sh clean    stop, then delete the state folder (accounting database,
#                                   job state, logs); the next start begins afresh
#
# Everything lives in one state folder, $TRIVSEL_SLURM_DIR (default /tmp/trivsel-slurm):
# etc/ (slurm.conf, slurmdbd.conf, cgroup.conf), pids/ (the PIDs this script started),
# log/, run/, spool/, mariadb/.  So that the SLURM commands (sinfo, sbatch, sacct) find the
# configuration without SLURM_CONF, start links /etc/slurm/slurm.conf to etc/slurm.conf when
# that file does not exist (stop removes the link again); otherwise export
# SLURM_CONF=$TRIVSEL_SLURM_DIR/etc/slurm.conf.
#
# Cluster "trivsel", partition "debug" (the default), account "trivsel" (the default account of
# root and of $SUDO_USER).  Ports: 6817-6819 (SLURM) and $TRIVSEL_SLURM_DB_PORT (default 3306)
# for a private MariaDB on 127.0.0.1.
set -euo pipefail

STATE=${TRIVSEL_SLURM_DIR:-/tmp/trivsel-slurm}
DB_PORT=${TRIVSEL_SLURM_DB_PORT:-3306}
CLUSTER=trivsel
ACCOUNT=trivsel
PARTITION=debug
DB_NAME=trivsel_slurm_acct
DB_USER=trivsel_slurm
PACKAGES=(munge slurm-client slurmctld slurmd slurmdbd mariadb-server-core mariadb-client-core)
ETC_LINK=/etc/slurm/slurm.conf
export SLURM_CONF=$STATE/etc/slurm.conf

now_ms() { local t=${EPOCHREALTIME//[.,]/}; echo $((t / 1000)); }
T0=$(now_ms)
elapsed() { local d=$(( $(now_ms) - ${1:-$T0} )); printf '%d.%d' $((d / 1000)) $((d % 1000 / 100)); }
say() { printf '[%5ss] %s\n' "$(elapsed)" "$*"; }
die() { echo "slurm-local: error: $*" >&2; exit 1; }

# wait_for SECONDS DESCRIPTION COMMAND...: poll every 0.2 s until COMMAND succeeds
wait_for() {
    local limit=$1 what=$2; shift 2
    local end=$(( $(date +%s) + limit ))
    until "$@" >/dev/null 2>&1; do
        (( $(date +%s) < end )) || { echo "slurm-local: timed out after ${limit}s waiting for $what" >&2; return 1; }
        sleep 0.2
    done
}

# --- recorded PIDs: pids/<name> holds the PID of a daemon this script started
# the name of live process $1 (empty when it is gone or a zombie)
comm_of() { [[ $(awk '{print $3}' "/proc/$1/stat" 2>/dev/null) =~ ^[^ZX]$ ]] && cat "/proc/$1/comm" 2>/dev/null || true; }
recorded_pid() {  # prints the PID of daemon $1 if it was started here and is still that daemon
    local f=$STATE/pids/$1 pid
    [[ -f $f ]] || return 1
    pid=$(<"$f")
    [[ $pid =~ ^[0-9]+$ && $(comm_of "$pid") == "$1" ]] || return 1
    echo "$pid"
}
record() { mkdir -p "$STATE/pids"; echo "$2" >"$STATE/pids/$1"; }
# PIDs of running processes named $1 (to detect daemons this script did not start; never to kill)
others() {
    local mine p; mine=$(recorded_pid "$1" || true)
    for p in $(pgrep -x "$1"); do [[ $p != "$mine" && $(comm_of "$p") == "$1" ]] && echo "$p"; done; return 0
}
# read the PID a daemon wrote to its pid file, waiting for the file; check the name
pid_from_file() {
    local file=$1 name=$2 end=$(( $(date +%s) + 30 )) pid
    while :; do
        if [[ -s $file ]]; then
            pid=$(tr -dc 0-9 <"$file")
            [[ -n $pid && $(comm_of "$pid") == "$name" ]] && { echo "$pid"; return 0; }
        fi
        (( $(date +%s) < end )) || return 1
        sleep 0.1
    done
}
logtail() { [[ -f $1 ]] && { echo "--- last lines of $1:" >&2; tail -n 20 "$1" >&2; }; return 0; }

# --- packages
install_packages() {
    local missing=()
    for b in munged slurmctld slurmd slurmdbd sinfo sacct sbatch mariadbd mariadb-install-db mariadb; do
        command -v "$b" >/dev/null || missing+=("$b")
    done
    if ((${#missing[@]} == 0)); then say "packages: installed"; return; fi
    say "packages: installing ${PACKAGES[*]} (missing: ${missing[*]})"
    [[ $(id -u) == 0 ]] || die "installing packages needs root"
    local policy_added=0
    # keep the packages' maintainer scripts from starting services (Debian's policy-rc.d hook)
    if [[ ! -e /usr/sbin/policy-rc.d ]]; then
        printf '#!/bin/sh\nexit 101\n' >/usr/sbin/policy-rc.d && chmod 755 /usr/sbin/policy-rc.d && policy_added=1
    fi
    local apt=(env DEBIAN_FRONTEND=noninteractive apt-get -y -q -o Dpkg::Use-Pty=0 install --no-install-recommends)
    if ! "${apt[@]}" "${PACKAGES[@]}" >"$STATE/log/apt.log" 2>&1; then
        say "packages: apt-get update, then again"
        apt-get -q update >>"$STATE/log/apt.log" 2>&1 && "${apt[@]}" "${PACKAGES[@]}" >>"$STATE/log/apt.log" 2>&1 \
            || { ((policy_added)) && rm -f /usr/sbin/policy-rc.d; logtail "$STATE/log/apt.log"; die "apt-get install failed"; }
    fi
    ((policy_added)) && rm -f /usr/sbin/policy-rc.d
    say "packages: installed ($(dpkg-query -W -f '${Version}' slurmctld) slurm)"
}

# --- configuration
write_config() {
    local node cpus mem
    # this machine's CPUs (with their topology) and memory, as slurmd itself sees them
    node=$(slurmd -C 2>/dev/null | head -n 1 || true)
    if [[ $node =~ CPUs=([0-9]+) ]]; then
        node=$(sed -E 's/^NodeName=[^ ]+ //; s/ UpTime=.*//' <<<"$node")
    else
        cpus=$(nproc); mem=$(awk '/^MemTotal:/ {print int($2 / 1024)}' /proc/meminfo)
        node="CPUs=$cpus RealMemory=$mem"
    fi
    local db_host=127.0.0.1 db_port="StoragePort=$DB_PORT"
    if [[ $(cat "$STATE/db-mode" 2>/dev/null) == external ]]; then db_host=localhost; db_port="# default socket"; fi
    mkdir -p "$STATE/etc"
    cat >"$STATE/etc/slurm.conf.new" <<EOF
# Written by scripts/slurm-local.sh: a single-node SLURM on localhost.
ClusterName=$CLUSTER
SlurmctldHost=localhost
SlurmUser=slurm
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
SlurmctldPort=6817
SlurmdPort=6818
StateSaveLocation=$STATE/spool/slurmctld
SlurmdSpoolDir=$STATE/spool/slurmd
SlurmctldPidFile=$STATE/run/slurmctld.pid
SlurmdPidFile=$STATE/run/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
MailProg=/bin/true
MpiDefault=none
SwitchType=switch/none
# no cgroups to rely on (containers, VMs without systemd): track processes through /proc
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=30
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=512
ReturnToService=2
InactiveLimit=0
KillWait=5
MinJobAge=300
SlurmctldTimeout=30
SlurmdTimeout=60
# job accounting through slurmdbd (the executor plugin polls sacct); the comment field holds
# the rule name and wildcards that Snakemake submits with --comment
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
AccountingStoragePort=6819
AccountingStoreFlags=job_comment
JobCompType=jobcomp/none
NodeName=localhost NodeAddr=127.0.0.1 $node State=UNKNOWN
PartitionName=$PARTITION Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF
    cat >"$STATE/etc/slurmdbd.conf.new" <<EOF
# Written by scripts/slurm-local.sh
AuthType=auth/munge
DbdHost=localhost
DbdPort=6819
SlurmUser=slurm
LogFile=$STATE/log/slurmdbd.log
PidFile=$STATE/run/slurmdbd.pid
StorageType=accounting_storage/mysql
# 127.0.0.1, not localhost: localhost would make the client use the default socket path
StorageHost=$db_host
$db_port
StorageUser=$DB_USER
StoragePass=$(<"$STATE/db-password")
StorageLoc=$DB_NAME
EOF
    cat >"$STATE/etc/cgroup.conf.new" <<EOF
# Written by scripts/slurm-local.sh.  slurm.conf uses proctrack/linuxproc and task/none, so no
# cgroup plugin is loaded and nothing is constrained; this file only states that.
ConstrainCores=no
ConstrainRAMSpace=no
ConstrainDevices=no
EOF
    local f changed=0
    for f in slurm.conf slurmdbd.conf cgroup.conf; do
        if cmp -s "$STATE/etc/$f.new" "$STATE/etc/$f"; then rm "$STATE/etc/$f.new"
        else mv "$STATE/etc/$f.new" "$STATE/etc/$f"; changed=1; fi
    done
    chown slurm:slurm "$STATE/etc/slurmdbd.conf"
    chmod 600 "$STATE/etc/slurmdbd.conf"
    chmod 644 "$STATE/etc/slurm.conf" "$STATE/etc/cgroup.conf"
    say "config: $STATE/etc ($( ((changed)) && echo written || echo unchanged); node $(grep -o 'CPUs=[0-9]*' <<<"$node"), $(grep -o 'RealMemory=[0-9]*' <<<"$node") MB)"
    if ((changed)) && recorded_pid slurmctld >/dev/null; then
        say "config: changed while the daemons run: stop, then start, to apply it"
    fi
    # the default configuration path, for the client commands
    if [[ -L $ETC_LINK && $(readlink "$ETC_LINK") == "$STATE/etc/slurm.conf" ]]; then :
    elif [[ ! -e $ETC_LINK && ! -L $ETC_LINK ]]; then
        mkdir -p /etc/slurm && ln -s "$STATE/etc/slurm.conf" "$ETC_LINK" && say "config: linked $ETC_LINK"
    else
        say "config: $ETC_LINK exists and is not ours: export SLURM_CONF=$SLURM_CONF to use this SLURM"
    fi
}

# --- munged
start_munge() {
    local pid
    if pid=$(recorded_pid munged); then say "munged: running (pid $pid)"; return; fi
    if [[ -n $(others munged) ]]; then
        munge -n 2>/dev/null | unmunge >/dev/null 2>&1 || die "a munged not started here is running but does not answer"
        say "munged: already running, not started here (left alone)"; rm -f "$STATE/pids/munged"; return
    fi
    if [[ ! -s /etc/munge/munge.key ]]; then
        mungekey --create --keyfile /etc/munge/munge.key >/dev/null 2>&1 \
            || dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
        chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
    fi
    install -d -o munge -g munge -m 755 /run/munge
    install -d -o munge -g munge -m 700 /var/lib/munge /var/log/munge
    rm -f /run/munge/munged.pid
    runuser -u munge -- /usr/sbin/munged </dev/null >"$STATE/log/munged.out" 2>&1 \
        || { logtail /var/log/munge/munged.log; die "munged did not start"; }
    pid=$(pid_from_file /run/munge/munged.pid munged) || die "munged wrote no pid file"
    record munged "$pid"
    wait_for 15 munged bash -c 'munge -n | unmunge' || die "munged does not answer"
    say "munged: started (pid $pid)"
}

# --- MariaDB: a private server on 127.0.0.1:$DB_PORT, or one that was already running
sql_private() { mariadb --no-defaults --protocol=socket --socket="$STATE/run/mariadb.sock" -u root "$@"; }
sql_external() { mariadb --protocol=socket -u root "$@"; }
start_mariadb() {
    local pid sql
    [[ -s $STATE/db-password ]] || { (umask 077; head -c 18 /dev/urandom | base64 | tr -dc A-Za-z0-9 >"$STATE/db-password"); }
    if pid=$(recorded_pid mariadbd); then
        say "mariadb: running (pid $pid)"; echo private >"$STATE/db-mode"; sql=sql_private
    elif [[ -n $(others mariadbd)$(others mysqld) ]]; then
        sql_external -e 'select 1' >/dev/null 2>&1 \
            || die "a MariaDB server not started here is running, and root cannot log in to it over its default socket"
        say "mariadb: already running, not started here (left alone; database $DB_NAME in it)"
        echo external >"$STATE/db-mode"; rm -f "$STATE/pids/mariadbd"; sql=sql_external
    else
        echo private >"$STATE/db-mode"; sql=sql_private
        local user=mysql
        id mysql >/dev/null 2>&1 || user=slurm   # the -core packages do not always create the mysql user
        if [[ ! -d $STATE/mariadb/mysql ]]; then
            rm -rf "$STATE/mariadb"; install -d -o "$user" -m 750 "$STATE/mariadb"
            mariadb-install-db --no-defaults --user="$user" --datadir="$STATE/mariadb" \
                --auth-root-authentication-method=socket --skip-test-db >"$STATE/log/mariadb-install.log" 2>&1 \
                || { logtail "$STATE/log/mariadb-install.log"; die "mariadb-install-db failed"; }
            say "mariadb: database files created in $STATE/mariadb"
        fi
        chown -R "$user" "$STATE/mariadb"
        rm -f "$STATE/run/mariadb.pid"
        setsid mariadbd --no-defaults --user="$user" --datadir="$STATE/mariadb" --socket="$STATE/run/mariadb.sock" \
            --port="$DB_PORT" --bind-address=127.0.0.1 --skip-name-resolve --pid-file="$STATE/run/mariadb.pid" \
            --log-error="$STATE/log/mariadb.log" --innodb-buffer-pool-size=64M \
            </dev/null >>"$STATE/log/mariadb.log" 2>&1 &
        pid=$!
        record mariadbd "$pid"
        wait_for 60 "mariadb" sql_private -e 'select 1' || { logtail "$STATE/log/mariadb.log"; die "mariadb did not start"; }
        pid=$(pid_from_file "$STATE/run/mariadb.pid" mariadbd) || die "mariadbd wrote no pid file"
        record mariadbd "$pid"
        say "mariadb: started (pid $pid, 127.0.0.1:$DB_PORT)"
    fi
    local pw; pw=$(<"$STATE/db-password")
    $sql <<EOF || die "could not create the accounting database"
CREATE DATABASE IF NOT EXISTS $DB_NAME;
CREATE USER IF NOT EXISTS '$DB_USER'@'localhost' IDENTIFIED BY '$pw';
CREATE USER IF NOT EXISTS '$DB_USER'@'127.0.0.1' IDENTIFIED BY '$pw';
ALTER USER '$DB_USER'@'localhost' IDENTIFIED BY '$pw';
ALTER USER '$DB_USER'@'127.0.0.1' IDENTIFIED BY '$pw';
GRANT ALL ON $DB_NAME.* TO '$DB_USER'@'localhost';
GRANT ALL ON $DB_NAME.* TO '$DB_USER'@'127.0.0.1';
EOF
}

# --- the SLURM daemons: started in the foreground (-D), detached; their PID is $!
start_slurm_daemon() {
    local name=$1 pid; shift
    if pid=$(recorded_pid "$name"); then say "$name: running (pid $pid)"; return 1; fi
    [[ -z $(others "$name") ]] || die "a $name not started by this script is running (pid $(others "$name" | paste -sd " ")); stop it first"
    rm -f "$STATE/run/$name.pid"
    setsid "$name" -D "$@" </dev/null >>"$STATE/log/$name.out" 2>&1 &
    pid=$!
    sleep 0.2
    # $! is the daemon itself (setsid execs it); else the PID the daemon wrote
    [[ $(comm_of "$pid") == "$name" ]] || pid=$(pid_from_file "$STATE/run/$name.pid" "$name") \
        || { logtail "$STATE/log/$name.log"; logtail "$STATE/log/$name.out"; die "$name exited at once"; }
    record "$name" "$pid"
}

sacctmgr_answers() { sacctmgr -n -P list cluster format=cluster; }
ensure_associations() {
    local users=(root) u
    [[ -n ${SUDO_USER:-} && ${SUDO_USER} != root ]] && users+=("$SUDO_USER")
    [[ -n $(sacctmgr -n -P list cluster where name=$CLUSTER format=cluster) ]] \
        || sacctmgr -i add cluster "$CLUSTER" >/dev/null || die "sacctmgr add cluster failed"
    [[ -n $(sacctmgr -n -P list account where name=$ACCOUNT format=account) ]] \
        || sacctmgr -i add account "$ACCOUNT" Cluster="$CLUSTER" Description=trivsel Organization=trivsel >/dev/null \
        || die "sacctmgr add account failed"
    for u in "${users[@]}"; do
        [[ -n $(sacctmgr -n -P list assoc where user="$u" account=$ACCOUNT cluster=$CLUSTER format=user) ]] \
            || sacctmgr -i add user "$u" Account="$ACCOUNT" DefaultAccount="$ACCOUNT" Cluster="$CLUSTER" >/dev/null \
            || die "sacctmgr add user $u failed"
    done
    say "accounting: cluster $CLUSTER, account $ACCOUNT, users ${users[*]}"
}

node_idle() { [[ $(sinfo -h -n localhost -o %T 2>/dev/null) =~ ^(idle|mixed|allocated) ]]; }
sacct_answers() { sacct -n -X -S now-1minute -o JobID >/dev/null; }

cmd_start() {
    [[ $(id -u) == 0 ]] || die "run as root (it installs packages and starts daemons)"
    local t_start; t_start=$(now_ms)
    mkdir -p "$STATE"/{etc,pids,log,run,spool/slurmd}
    chmod 755 "$STATE"
    install_packages
    chown slurm:slurm "$STATE/log" "$STATE/run"
    install -d -o slurm -g slurm "$STATE/spool/slurmctld"
    start_munge
    start_mariadb
    write_config
    if start_slurm_daemon slurmdbd; then
        wait_for 60 "slurmdbd" sacctmgr_answers || { logtail "$STATE/log/slurmdbd.log"; die "slurmdbd does not answer"; }
        say "slurmdbd: started (pid $(recorded_pid slurmdbd))"
    fi
    ensure_associations   # the cluster must be known before slurmctld starts
    if start_slurm_daemon slurmctld; then
        wait_for 60 "slurmctld" scontrol ping || { logtail "$STATE/log/slurmctld.log"; die "slurmctld does not answer"; }
        say "slurmctld: started (pid $(recorded_pid slurmctld))"
    fi
    if start_slurm_daemon slurmd -N localhost; then say "slurmd: started (pid $(recorded_pid slurmd))"; fi
    if ! wait_for 60 "the node to be idle" node_idle; then
        # a node left down or drained by an earlier run: resume it once
        scontrol update nodename=localhost state=resume >/dev/null 2>&1 || true
        wait_for 30 "the node to be idle" node_idle || { sinfo -N -l >&2 || true; logtail "$STATE/log/slurmd.log"; die "node not idle"; }
    fi
    say "node: $(sinfo -h -N -o '%N %T cpus=%c mem=%mMB partition=%P')"
    wait_for 60 "sacct" sacct_answers || die "sacct does not answer"
    say "sacct: answers; SLURM ready in $(elapsed "$t_start") s"
}

# stop_daemon NAME: TERM the recorded daemon, wait (then KILL), wait until it is reaped
stop_daemon() {
    local name=$1 pid i
    if ! pid=$(recorded_pid "$name"); then
        [[ -f $STATE/pids/$name ]] && { rm -f "$STATE/pids/$name"; say "$name: not running (stale record removed)"; }
        return 0
    fi
    kill -TERM "$pid" 2>/dev/null || true
    for ((i = 0; i < 300; i++)); do [[ $(comm_of "$pid") == "$name" ]] || break; sleep 0.1; done
    local how=stopped
    if [[ $(comm_of "$pid") == "$name" ]]; then kill -KILL "$pid" 2>/dev/null || true; how=killed; fi
    # until its parent (init) has reaped it, an exited daemon is still listed, as <defunct>
    for ((i = 0; i < 50; i++)); do [[ -e /proc/$pid && -z $(comm_of "$pid") ]] || break; sleep 0.1; done
    say "$name: $how (pid $pid)"
    rm -f "$STATE/pids/$name"
}

cmd_stop() {
    if recorded_pid slurmctld >/dev/null; then
        local jobs
        jobs=$(squeue -h -o %A 2>/dev/null || true)
        if [[ -n $jobs ]]; then
            # slurmstepd outlives slurmd: cancel the jobs while slurmd still runs, wait until they are gone
            scancel $jobs 2>/dev/null || true
            wait_for 30 "the jobs to end" bash -c '[[ -z $(squeue -h -o %A) ]]' || true
            say "jobs: cancelled $(wc -w <<<"$jobs")"
        fi
    fi
    stop_daemon slurmd & stop_daemon slurmctld & wait
    stop_daemon slurmdbd
    stop_daemon mariadbd & stop_daemon munged & wait
    if [[ -L $ETC_LINK && $(readlink "$ETC_LINK") == "$STATE/etc/slurm.conf" ]]; then
        rm -f "$ETC_LINK"; say "config: unlinked $ETC_LINK"
    fi
    say "stopped (state kept in $STATE)"
}

cmd_status() {
    local name pid rc=0
    for name in munged mariadbd slurmdbd slurmctld slurmd; do
        if pid=$(recorded_pid "$name"); then echo "$name: running (pid $pid, started here)"
        elif [[ -n $(others "$name") ]]; then echo "$name: running (pid $(others "$name" | paste -sd " "), not started here)"
        else echo "$name: not running"; [[ $name == slurm* ]] && rc=1; fi
    done
    if ((rc == 0)); then
        sinfo -N -o '%N %T cpus=%c mem=%mMB partition=%P' || rc=1
        squeue || rc=1
    fi
    return $rc
}

case ${1:-} in
    start) cmd_start ;;
    stop) cmd_stop ;;
    status) cmd_status ;;
    clean) cmd_stop; rm -rf "$STATE"; echo "removed $STATE" ;;
    *) echo "usage: $0 start|status|stop|clean" >&2; exit 2 ;;
esac
