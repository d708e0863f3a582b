#!/usr/bin/env bash
# The Debian package end to end, on this machine: build it with CPack from
# the build tree, check its control fields and contents, install it with
# dpkg -i, verify the installed units with systemd-analyze, run the
# installed craftscand (as the craftscan user the package created, with the
# installed config) on the simulated station and calibrate and scan with the
# installed craftscanctl, serve the installed console's files with the
# installed craftscan-web, then dpkg -r and dpkg -P and check that nothing
# of the package is left.
#
#   test_package.sh BUILD_DIR VERSION
#
# Needs root (dpkg -i installs system-wide) and dpkg; skipped (exit 77)
# without them, or when a craftscan package this test did not install is
# present (it is never touched). Whatever happens, the exit trap stops what
# it started and purges the package it installed; a run killed before its
# trap could run leaves a marker, and the next run purges its leftovers.
#
# Deviations from the shipped set-up, for speed and isolation: the sim
# renders 640x512 instead of 1280x1024 (a copy of the installed
# craftscand.yaml with that one value changed); CRAFTSCAN_* overrides set the
# station id, DDS domain, data_dir and tokens file, 10 calibration views and
# the carved box's working volume; the installed cyclonedds.xml is read
# through CYCLONEDDS_URI with a loopback-only addition.
set -euo pipefail

build=${1:?usage: test_package.sh BUILD_DIR VERSION}
version=${2:?usage: test_package.sh BUILD_DIR VERSION}
prog=test_package
marker=/var/tmp/craftscan-package-test.marker
start=$SECONDS

say() { echo "$prog [$((SECONDS - start)) s]: $*"; }
skip() {
  echo "$prog: SKIPPED: $*"
  exit 77
}
fail() {
  echo "$prog: FAILED: $*" >&2
  exit 1
}

[[ $(id -u) == 0 ]] || skip "needs root: it installs the craftscan package system-wide (dpkg -i)"
for tool in dpkg dpkg-deb dpkg-query cpack python3 setpriv; do
  command -v "$tool" >/dev/null || skip "$tool not found (dpkg, dpkg-dev, cmake, python3, util-linux)"
done
command -v dpkg-shlibdeps >/dev/null || skip "dpkg-shlibdeps not found (package dpkg-dev)"
[[ -f $build/CPackConfig.cmake ]] || fail "$build/CPackConfig.cmake missing: configure the build first"

installed_state() { dpkg-query -W -f='${db:Status-Status}' craftscan 2>/dev/null || true; }

# --- A run that died before its cleanup ---------------------------------------
if [[ -f $marker ]]; then
  say "removing what an earlier, interrupted run left ($(head -n 1 "$marker"))"
  while read -r key value; do
    # Its folder.
    if [[ $key == dir && $value == /tmp/craftscan-package-test-* ]]; then rm -rf "$value"; fi
    # Its daemon or console, if still running (checked by executable).
    if [[ $key == pid && -d /proc/$value ]]; then
      case $(readlink "/proc/$value/exe" 2>/dev/null) in
        /usr/bin/craftscand* | /usr/bin/craftscan-web* | */python3*) kill -KILL "$value" 2>/dev/null || true ;;
      esac
    fi
  done <"$marker"
  [[ -z $(installed_state) || $(installed_state) == not-installed ]] || dpkg -P craftscan >/dev/null
  rm -f "$marker"
fi
state=$(installed_state)
if [[ -n $state && $state != not-installed ]]; then
  skip "a craftscan package this test did not install is on this machine (dpkg: $state): not touching it"
fi

work=$(mktemp -d /tmp/craftscan-package-test-XXXXXX)
pids=()
cleanup() {
  local rc=$?
  for pid in "${pids[@]}"; do
    {
      kill -KILL "$pid" && wait "$pid"
    } 2>/dev/null || true
  done
  if [[ -f $marker ]]; then
    local s
    s=$(installed_state)
    if [[ -n $s && $s != not-installed ]]; then
      echo "$prog: cleanup: purging the craftscan package this test installed" >&2
      dpkg -P craftscan >/dev/null 2>&1 || echo "$prog: cleanup: dpkg -P craftscan failed" >&2
    fi
    rm -f "$marker"
  fi
  rm -rf "$work"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 143' TERM INT HUP
remember_pid() {
  pids+=("$1")
  echo "pid $1" >>"$marker"
}

# --- Build the package ----------------------------------------------------------
say "building the package with cpack (dpkg-shlibdeps takes most of a minute)"
if ! cpack --config "$build/CPackConfig.cmake" -G DEB -B "$work/pkg" >"$work/cpack.log" 2>&1; then
  cat "$work/cpack.log" >&2
  fail "cpack -G DEB failed (above)"
fi
deb=$work/pkg/craftscan_${version}_$(dpkg --print-architecture).deb
[[ -f $deb ]] || fail "no $deb; cpack made: $(ls "$work/pkg")"
say "built $(basename "$deb"), $(stat -c %s "$deb") bytes"

# --- Control fields --------------------------------------------------------------
field() { dpkg-deb -f "$deb" "$1"; }
[[ $(field Package) == craftscan ]] || fail "Package: $(field Package)"
[[ $(field Version) == "$version" ]] || fail "Version: $(field Version), the project's is $version"
depends=$(field Depends)
# dpkg-shlibdeps' libraries and the hand-written ones.
for dep in 'systemd | systemd-standalone-sysusers' 'libc6 (' 'libstdc++6 (' 'libddsc0debian (' \
  'libopencv-core406 (' 'libpcl-common1.13 (' 'libaravis-0.8-0 (' 'libyaml-cpp0.7 (' 'libsystemd0'; do
  [[ $depends == *"$dep"* ]] || fail "Depends lacks '$dep': $depends"
done
dpkg-deb --ctrl-tarfile "$deb" | tar -t >"$work/control.list"
for f in ./postinst ./prerm ./postrm ./conffiles ./md5sums; do
  grep -qx "$f" "$work/control.list" || fail "control archive lacks $f: $(tr '\n' ' ' <"$work/control.list")"
done
conffiles=$(dpkg-deb -I "$deb" conffiles | sort | tr '\n' ' ')
[[ $conffiles == "/etc/craftscan/craftscan-worker.yaml /etc/craftscan/craftscand.yaml /etc/craftscan/cyclonedds.xml /etc/craftscan/web.yaml " ]] ||
  fail "conffiles: $conffiles"

# --- Contents --------------------------------------------------------------------
dpkg-deb -c "$deb" | awk '{print $1, $6}' >"$work/contents"
expect_file() { # MODE PATH
  grep -qx -- "$1 .$2" "$work/contents" || fail "package lacks $2 (mode $1); it has:
$(grep -v /assets/ "$work/contents")"
}
for p in craftscand craftscanctl craftscan-record craftscan-web craftscan-worker; do expect_file -rwxr-xr-x /usr/bin/$p; done
for d in sim aravis serial_turntable; do
  expect_file -rw-r--r-- /usr/lib/craftscan/drivers/craftscan-driver-$d.so
done
for f in /lib/systemd/system/craftscand.service /lib/systemd/system/craftscan-web.service \
  /lib/systemd/system/craftscan-worker.service /etc/craftscan/craftscan-worker.yaml \
  /usr/lib/sysusers.d/craftscan.conf /lib/udev/rules.d/70-craftscan-cameras.rules \
  /usr/lib/sysctl.d/60-craftscan.conf /etc/craftscan/craftscand.yaml /etc/craftscan/cyclonedds.xml \
  /etc/craftscan/web.yaml /usr/share/craftscan/web/assets/index.html \
  /usr/share/craftscan/web/assets/viewer.bundle.js /usr/share/craftscan/security/governance.xml \
  /usr/share/craftscan/security/permissions.xml; do
  expect_file -rw-r--r-- "$f"
done
expect_file -rwxr-xr-x /usr/sbin/craftscan-dds-security-setup
# Nothing of the build or the tests.
if grep -E 'test|/build/|\.a$|gtest|hardened' "$work/contents" | grep -v /assets/ >"$work/stray"; then
  fail "unexpected files in the package: $(cat "$work/stray")"
fi

# --- Install ---------------------------------------------------------------------
printf 'installed %s by %s\ndir %s\n' "$(date -u +%FT%TZ)" "$prog" "$work" >"$marker"
say "dpkg -i"
if ! dpkg -i "$deb" >"$work/dpkg-i.log" 2>&1; then
  cat "$work/dpkg-i.log" >&2
  if grep -q 'dependency problems' "$work/dpkg-i.log"; then
    fail "dpkg -i: craftscan's dependencies are not all installed on this machine (above); \
install them (apt-get install -f, or scripts/setup) and run again"
  fi
  fail "dpkg -i failed (above)"
fi
[[ $(installed_state) == installed ]] || fail "dpkg status after dpkg -i: $(installed_state)"
dpkg -L craftscan | sort >"$work/installed.list"
# The postinst made the user, in the groups the unit and the udev rules use.
id craftscan >/dev/null 2>&1 || fail "no craftscan user after dpkg -i (postinst's systemd-sysusers)"
groups=$(id -nG craftscan)
for g in craftscan plugdev dialout; do
  [[ " $groups " == *" $g "* ]] || fail "user craftscan not in group $g: $groups"
done
# Installing over itself, as an upgrade does (postinst configure with the
# old version): a site's edit to a conffile survives.
echo "# edited by $prog" >>/etc/craftscan/web.yaml
dpkg -i "$deb" >"$work/dpkg-i2.log" 2>&1 || fail "dpkg -i over the installed package: $(cat "$work/dpkg-i2.log")"
grep -q "^# edited by $prog" /etc/craftscan/web.yaml || fail "reinstalling lost the edit to /etc/craftscan/web.yaml"
[[ $(/usr/bin/craftscanctl --version) == *"$version"* ]] || fail "craftscanctl --version: $(/usr/bin/craftscanctl --version)"
[[ $(/usr/bin/craftscan-worker --version) == *"$version"* ]] ||
  fail "craftscan-worker --version: $(/usr/bin/craftscan-worker --version)"

# --- systemd-analyze verify ------------------------------------------------------
if command -v systemd-analyze >/dev/null; then
  set +e
  systemd-analyze verify --man=no /lib/systemd/system/craftscand.service \
    /lib/systemd/system/craftscan-web.service /lib/systemd/system/craftscan-worker.service \
    >"$work/verify.out" 2>"$work/verify.err"
  verify_rc=$?
  set -e
  # Parse problems are only warnings on stderr (exit 0): any line naming a
  # unit or sounding like a problem fails.
  if ((verify_rc != 0)) || grep -E 'craftscan|Unknown|unknown|Failed|[Ii]nvalid|ignoring|not executable|Missing|[Ee]rror|deprecated' \
    "$work/verify.err" >"$work/verify.problems"; then
    cat "$work/verify.err" >&2
    fail "systemd-analyze verify of the installed units: exit $verify_rc (above)"
  fi
  say "systemd-analyze verify: the installed units are clean"
else
  say "systemd-analyze not installed (package systemd): unit verification not done"
fi

# --- The installed daemon on the simulated station -----------------------------
run=$work/run
mkdir -p "$run/data"
chmod 0755 "$work" "$run"
token=package-test-admin-$RANDOM$RANDOM$RANDOM
printf 'tokens:\n  - {name: package-test, token: "%s", role: admin}\n' "$token" >"$run/tokens.yaml"
chown craftscan:craftscan "$run/data" "$run/tokens.yaml"
chmod 0600 "$run/tokens.yaml"
chmod 0750 "$run/data"
sed 's/image_size: 1280x1024/image_size: 640x512/' /etc/craftscan/craftscand.yaml >"$run/craftscand.yaml"
grep -q 'image_size: 640x512' "$run/craftscand.yaml" ||
  fail "the installed craftscand.yaml has no 'image_size: 1280x1024' to shrink"

station=pkgtest$$
domain=$((1 + RANDOM % 230))
loopback='<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
loopback+='<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
loopback+='<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
loopback+='</Discovery></Domain></CycloneDDS>'
export CYCLONEDDS_URI="file:///etc/craftscan/cyclonedds.xml,$loopback"
export CRAFTSCAN_STATION=$station CRAFTSCAN_DDS_DOMAIN=$domain CRAFTSCAN_DATA_DIR=$run/data
export CRAFTSCAN_AUTH_TOKENS_FILE=$run/tokens.yaml CRAFTSCAN_DDS_CONFIG_FILE=
# 10 board views, the fewest a calibration accepts (15 in the example config),
# and the carved box's working volume with a margin, as the daemon tests use:
# the matcher searches that band of disparities only.
export CRAFTSCAN_CALIBRATION_VIEWS=10 CRAFTSCAN_PIPELINE_VOLUME_RADIUS_MM=65
export CRAFTSCAN_PIPELINE_VOLUME_MAX_HEIGHT_MM=70 CRAFTSCAN_PIPELINE_PLATTER_RADIUS_MM=0
unset CRAFTSCAN_TOKEN NOTIFY_SOCKET WATCHDOG_USEC WATCHDOG_PID

/usr/bin/craftscand --config "$run/craftscand.yaml" --print-config >"$run/effective.yaml"
grep -q 'path: \["/usr/lib/craftscan/drivers"\]' "$run/effective.yaml" ||
  fail "plugins.path is not the package's /usr/lib/craftscan/drivers: $(grep -A1 '^plugins' "$run/effective.yaml")"

# The service manager's end of sd_notify, as the unit's Type=notify uses it.
python3 - "$run/notify" "$run/notify.log" <<'EOF' &
import os, socket, sys
path, log = sys.argv[1], sys.argv[2]
s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
s.bind(path)
os.chmod(path, 0o666)  # the daemon runs as craftscan
with open(log, "a") as out:
    while True:
        out.write(s.recv(65536).decode(errors="replace") + "\n")
        out.flush()
EOF
remember_pid $!
for _ in $(seq 100); do [[ -S $run/notify ]] && break; sleep 0.1; done
[[ -S $run/notify ]] || fail "the fake notify socket did not appear"

say "starting /usr/bin/craftscand as user craftscan (station $station, DDS domain $domain)"
NOTIFY_SOCKET=$run/notify setpriv --reuid=craftscan --regid=craftscan --init-groups --inh-caps=-all \
  /usr/bin/craftscand --config "$run/craftscand.yaml" >"$run/craftscand.log" 2>&1 &
daemon=$!
remember_pid $daemon
daemon_log() { tail -n 40 "$run/craftscand.log"; }
for _ in $(seq 600); do
  grep -qx 'READY=1' "$run/notify.log" 2>/dev/null && break
  kill -0 $daemon 2>/dev/null || fail "craftscand exited before READY=1:
$(daemon_log)"
  sleep 0.1
done
grep -qx 'READY=1' "$run/notify.log" || fail "no READY=1 within 60 s:
$(daemon_log)"
say "craftscand ready: $(grep '^STATUS=' "$run/notify.log" | tail -1)"

ctl() { /usr/bin/craftscanctl --station "$station" --domain "$domain" --token "$token" --timeout 30 "$@"; }
ctl_ok() { # NAME ARGS...: runs craftscanctl, fails the test on a non-zero exit
  local name=$1
  shift
  if ! ctl "$@" >"$run/$name.out" 2>"$run/$name.err"; then
    fail "craftscanctl $* failed:
$(cat "$run/$name.out" "$run/$name.err")
daemon log:
$(daemon_log)"
  fi
}
ctl_ok status --json status
python3 - "$run/status.out" <<'EOF' || fail "status: $(cat "$run/status.out")"
import json, sys
s = json.load(open(sys.argv[1]))
# Both sim devices came from the installed plugin and are open.
devices = {d["name"]: d for d in s["devices"]}
assert devices["camera"]["driver"] == "sim" and devices["camera"]["state"] == "Streaming", devices
assert devices["turntable"]["driver"] == "sim" and devices["turntable"]["state"] == "Ready", devices
assert s["calibration_id"] == "", s["calibration_id"]  # a new data_dir
assert s["storage"]["ok"], s["storage"]
EOF
say "calibrating (10 board views) and finding the turntable axis"
ctl_ok calibrate calibrate
ctl_ok calibrate-turntable calibrate-turntable
say "scanning 3 views"
ctl_ok scan --json scan --object "package test box" --views 3 --step 120
session=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["session"])' "$run/scan.out")
python3 - "$run/scan.out" <<'EOF' || fail "scan result: $(head -c 2000 "$run/scan.out")"
import json, sys
job = json.load(open(sys.argv[1]))
assert job["state"] == "done", job["state"]
r = job["result"]
assert r["views"] == 3, r["views"]
assert r["fused_points"] > 5000, r["fused_points"]
# The sim's carved box is 80 x 60 x 50 mm; the measured box within 2 mm.
dims = sorted(r["measurement"]["box"]["dims_mm"], reverse=True)
for got, true in zip(dims, (80, 60, 50)):
    assert abs(got - true) < 2.0, (dims, "vs 80 x 60 x 50 mm")
print("  box %.2f x %.2f x %.2f mm, %d fused points" % (*dims, r["fused_points"]))
EOF
say "scan done: session $session; fetching it"
ctl_ok get get "$session" --out "$run/fetched"
# The session on the station's disk: done, written by the craftscan user,
# and the fetched outputs equal to it.
sdir=$run/data/sessions/$session
python3 - "$sdir/manifest.json" <<'EOF' || fail "manifest: $(head -c 2000 "$sdir/manifest.json")"
import json, sys
m = json.load(open(sys.argv[1]))
assert m["state"] == "done", m["state"]
EOF
for f in fused.ply mesh.ply mesh.obj report.json report.html; do
  [[ -s $sdir/$f ]] || fail "session $session has no $f"
  [[ $(stat -c %U "$sdir/$f") == craftscan ]] || fail "$sdir/$f owned by $(stat -c %U "$sdir/$f")"
  cmp -s "$sdir/$f" "$run/fetched/$f" || fail "craftscanctl get: $f differs from the session's"
done

# --- The installed console serves the installed files ---------------------------
sed -e "s#^cache_dir: .*#cache_dir: $run/web-cache#" -e "s#^stations: .*#stations: [$station]#" \
  -e "s#^domain_id: .*#domain_id: $domain#" /etc/craftscan/web.yaml >"$run/web.yaml"
mkdir -p "$run/web-cache" && chown craftscan:craftscan "$run/web-cache"
port=$((20000 + RANDOM % 20000))
setpriv --reuid=craftscan --regid=craftscan --init-groups --inh-caps=-all \
  /usr/bin/craftscan-web --config "$run/web.yaml" --listen "127.0.0.1:$port" >"$run/web.log" 2>&1 &
web=$!
remember_pid $web
index=/usr/share/craftscan/web/assets/index.html
for _ in $(seq 100); do
  curl -sf -o "$run/index.html" "http://127.0.0.1:$port/assets/index.html" && break
  kill -0 $web 2>/dev/null || fail "craftscan-web exited: $(tail -20 "$run/web.log")"
  sleep 0.2
done
cmp -s "$run/index.html" "$index" || fail "craftscan-web did not serve $index: $(tail -20 "$run/web.log")"
kill -TERM $web
wait $web || true
say "craftscan-web served $index"

# --- Stop as systemd would --------------------------------------------------------
kill -TERM $daemon
set +e
wait $daemon
daemon_rc=$?
set -e
((daemon_rc == 0)) || fail "craftscand exit $daemon_rc after SIGTERM: $(daemon_log)"
grep -qx 'STOPPING=1' "$run/notify.log" || fail "no STOPPING=1 on SIGTERM"

# --- Remove, then purge -----------------------------------------------------------
say "dpkg -r"
dpkg -r craftscan >"$work/dpkg-r.log" 2>&1 || fail "dpkg -r: $(cat "$work/dpkg-r.log")"
[[ $(installed_state) == config-files ]] || fail "dpkg status after dpkg -r: $(installed_state)"
[[ ! -e /usr/bin/craftscand && ! -e /usr/lib/craftscan/drivers/craftscan-driver-sim.so ]] ||
  fail "dpkg -r left the programs"
[[ -f /etc/craftscan/craftscand.yaml ]] || fail "dpkg -r removed the conffiles (only purge should)"
say "dpkg -P"
dpkg -P craftscan >"$work/dpkg-p.log" 2>&1 || fail "dpkg -P: $(cat "$work/dpkg-p.log")"
s=$(installed_state)
[[ -z $s || $s == not-installed ]] || fail "dpkg status after dpkg -P: $s"
left=()
while read -r path; do
  # Directories other packages share (/usr/bin, /lib/systemd/system, ...) stay.
  if [[ -d $path && $path != */craftscan* ]]; then continue; fi
  if [[ -e $path || -L $path ]]; then left+=("$path"); fi
done <"$work/installed.list"
((${#left[@]} == 0)) || fail "left after dpkg -P: ${left[*]}"
[[ ! -e /etc/craftscan && ! -e /var/cache/craftscan-web ]] || fail "/etc/craftscan or /var/cache/craftscan-web left"
rm -f "$marker"
# Kept on purpose (postrm): the craftscan user, and /var/lib/craftscan's scans
# (this test wrote none there).
say "removed cleanly ($(wc -l <"$work/installed.list") paths); the craftscan user is kept, as Debian does"
say "passed"
