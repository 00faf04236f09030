#!/usr/bin/env bash
# Runs the current end-to-end tests (the test targets of the root package, tests/*.rs) against
# another `chaoscope` binary, to check that a test catches a regression: a test written for a
# fix should fail against the binary from before the fix and pass against the current one.
#
# Usage (from anywhere in the repository; as root for tests/other_users.rs, as CI runs):
#
#   tests/against-binary.sh [--only FILE,...] [--timeout SECONDS] [--log-dir DIR] BINARY|COMMIT
#
#   BINARY  a path to a chaoscope executable (e.g. one kept from an older build);
#   COMMIT  anything `git rev-parse` names (0b8441d, main~3, a tag): its binary is built with
#           `cargo build --release --bin chaoscope` in a temporary `git worktree` with its own
#           target directory (CHAOSCOPE_AGAINST_TARGET=DIR keeps and reuses one), removed after.
#   --only     comma-separated test files (names of tests/*.rs without .rs: a module of the
#              end_to_end binary, or a target of its own); default all.
#   --timeout  seconds allowed per test function (default 900), after which it counts as failed.
#   --log-dir  where each test's output is kept (default target/against-binary/logs/<binary>/).
#
# What it does: builds the current tests (`cargo test --release --no-run`), moves the real
# `target/release/chaoscope` aside (the tests run the path `env!("CARGO_BIN_EXE_chaoscope")`
# compiled into them, tests/common), puts a copy of the given binary in its place, runs each
# test function of each test executable directly (never through cargo, so nothing is rebuilt),
# one at a time (`--exact NAME --test-threads=1 --nocapture`, in the package directory as cargo
# does; a test killed at the timeout keeps its output so far in its log), and
# always puts the real binary back (on exit, Ctrl+C or SIGTERM; a run killed with SIGKILL leaves
# it as `chaoscope.against-real`, which the next run of this script restores first). The copy
# carries a 1970 modification time, so a cargo build that ever saw it would rebuild it rather
# than take it for its own. Tests marked #[ignore] are not run. Do not build in the same target
# directory while this runs.
#
# Output: one JSON line per test function on standard output,
#   {"test": "end_to_end::output_paths::no_writer_...", "binary": "...", "sha256": "...", "passed": false,
#    "outcome": "failed", "seconds": 12.3, "log": ".../end_to_end__output_paths__no_writer_....log"}
# (outcome: "passed", "failed" or "timeout"), and progress and a table on standard error:
#
#   tests/against-binary.sh /path/to/old/chaoscope > old.jsonl
#   tests/against-binary.sh target/release/chaoscope > new.jsonl    # the current binary itself
#
# Exit status: 0 when every test ran (whatever its result), non-zero when the script itself
# could not build, swap or run. Not part of CI: it takes as long as the tests it runs.
set -euo pipefail
# The tests stop commands with SIGINT, which a command started with SIGINT ignored keeps
# ignoring: started so (a script's `... &`), run again with SIGINT's default action, as .ci/run.
if (( 0x$(awk '/^SigIgn:/ { print $2 }' "/proc/$$/status") & 2 )); then
    exec env --default-signal=INT bash "$0" "$@"
fi
# Job control: each test runs in its own process group, so a test's children see SIGINT and
# SIGTERM with their default dispositions (a non-interactive shell would start background jobs
# with SIGINT ignored, which the signal tests and Python's KeyboardInterrupt depend on).
set -m

usage() {
    sed -n '/^# Usage/,/^#   --log-dir/p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
}

only=""
per_test_timeout=900
log_dir=""
arg=""
while (($# > 0)); do
    case "$1" in
    --only) only="${2:?--only needs a list}"; shift 2 ;;
    --timeout) per_test_timeout="${2:?--timeout needs seconds}"; shift 2 ;;
    --log-dir) log_dir="${2:?--log-dir needs a directory}"; shift 2 ;;
    -h | --help) usage ;;
    -*) echo "against-binary: unknown option $1" >&2; usage ;;
    *)
        [[ -z "$arg" ]] || { echo "against-binary: one binary or commit, not two" >&2; usage; }
        arg="$1"; shift ;;
    esac
done
[[ -n "$arg" ]] || usage
[[ "$per_test_timeout" =~ ^[0-9]+$ ]] || { echo "against-binary: --timeout takes whole seconds" >&2; exit 2; }

say() { echo "against-binary: $*" >&2; }

repo="$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
cd "$repo"
target_dir="$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')"
real_bin="$target_dir/release/chaoscope"
backup="$real_bin.against-real"
scratch="$target_dir/against-binary"
mkdir -p "$scratch"

# A previous run killed before its cleanup left the real binary aside: put it back first.
if [[ -e "$backup" ]]; then
    say "restoring $real_bin left aside by an interrupted earlier run"
    mv -f "$backup" "$real_bin"
fi

current_pid=""
test_tmp=""
commit_tree=""
commit_target=""
# Ends every process still working in a test's directory: an old binary's process that ignored
# the test's SIGTERM (a `record` partner of the signal matrix on 0b8441d ran on for an hour,
# burning a core) would otherwise outlive its test and slow every later one.
reap() {
    pkill -KILL -f -- "$1" 2>/dev/null || true
}

cleanup() {
    if [[ -n "$current_pid" ]]; then
        # timeout(1) forwards the signal to the test's whole process group.
        kill -TERM "$current_pid" 2>/dev/null || true
        wait "$current_pid" 2>/dev/null || true
        current_pid=""
    fi
    if [[ -n "$test_tmp" ]]; then
        reap "$test_tmp"
        rm -rf "$test_tmp"
        test_tmp=""
    fi
    if [[ -e "$backup" ]]; then
        mv -f "$backup" "$real_bin"
        say "restored the real $real_bin"
    fi
    if [[ -n "$commit_tree" ]]; then
        git -C "$repo" worktree remove --force "$commit_tree" 2>/dev/null || true
        rm -rf "$(dirname "$commit_tree")"
        commit_tree=""
    fi
    if [[ -n "$commit_target" && -z "${CHAOSCOPE_AGAINST_TARGET:-}" ]]; then
        rm -rf "$commit_target"
        commit_target=""
    fi
}
trap cleanup EXIT
trap 'cleanup; exit 130' INT
trap 'cleanup; exit 143' TERM

# 1. The binary to test against: a file as given, or a commit built in its own worktree.
candidate="$scratch/candidate.$$"
if [[ -f "$arg" && -x "$arg" ]]; then
    label="$(realpath "$arg")"
    from_commit=""
elif sha="$(git rev-parse --verify --quiet "$arg^{commit}")"; then
    label="commit:$sha"
    from_commit="$sha"
else
    echo "against-binary: $arg is neither an executable file nor a commit" >&2
    exit 2
fi

if [[ -n "$from_commit" ]]; then
    commit_tree="$(mktemp -d "${TMPDIR:-/tmp}/chaoscope-against.XXXXXX")/src"
    commit_target="${CHAOSCOPE_AGAINST_TARGET:-$(dirname "$commit_tree")/target}"
    say "building chaoscope of $from_commit in $commit_tree (target $commit_target)"
    git -C "$repo" worktree add --detach --quiet "$commit_tree" "$from_commit"
    (cd "$commit_tree" && CARGO_TARGET_DIR="$commit_target" cargo build --release --bin chaoscope) >&2
    cp "$commit_target/release/chaoscope" "$scratch/chaoscope-${from_commit:0:12}"
    cleanup
    arg="$scratch/chaoscope-${from_commit:0:12}"
fi

# 2. The current tests (this also builds the real current binary at $real_bin).
say "building the current tests of the root package"
artifacts="$scratch/artifacts.$$.json"
cargo test --release --no-run -p chaoscope --tests --message-format=json >"$artifacts"
# name<TAB>executable for each test target (tests/*.rs) of the root package.
mapfile -t executables < <(python3 - "$artifacts" "$only" "$repo" <<'PY'
import json, sys
path, only, repo = sys.argv[1:]
seen = {}
for line in open(path):
    try:
        m = json.loads(line)
    except ValueError:
        continue
    if m.get("reason") != "compiler-artifact" or not m.get("executable"):
        continue
    t = m["target"]
    if "test" not in t["kind"] or not m["profile"]["test"]:
        continue
    # The root package's id is `path+file://<repository>#chaoscope@<version>`.
    if m["package_id"].startswith(f"path+file://{repo}#"):
        seen[t["name"]] = m["executable"]
for name in sorted(seen):
    print(f"{name}\t{seen[name]}")
PY
)
rm -f "$artifacts"
((${#executables[@]} > 0)) || { say "no test executables found"; exit 1; }

# Whether a test of target $1 named $2 is one of --only's files: the target itself, or the
# module of the end_to_end binary that the test's path starts with.
selected() {
    [[ -z "$only" ]] && return 0
    local file
    for file in ${only//,/ }; do
        [[ "$1" == "$file" || "$2" == "$file::"* ]] && return 0
    done
    return 1
}
# Every file --only names has a test, checked before anything is swapped.
if [[ -n "$only" ]]; then
    for file in ${only//,/ }; do
        found=""
        for entry in "${executables[@]}"; do
            name="${entry%%$'\t'*}"
            exe="${entry#*$'\t'}"
            # The list taken whole first: `grep -q` ends at its first match, and the harness
            # writing the rest into the closed pipe would fail the pipeline.
            tests="$("$exe" --list --format terse)"
            if [[ "$name" == "$file" ]] || grep -q "^$file::" <<<"$tests"; then
                found=1
                break
            fi
        done
        [[ -n "$found" ]] || { say "no test file $file"; exit 1; }
    done
fi

cp "$arg" "$candidate"
chmod 0755 "$candidate"
sha256="$(sha256sum "$candidate" | cut -d' ' -f1)"
version="$("$candidate" --version 2>/dev/null || echo unknown)"
say "testing against $label ($version, sha256 ${sha256:0:16})"

if [[ -n "$from_commit" ]]; then
    label_dir="commit-${from_commit:0:12}"
else
    label_dir="$(basename "$label")-${sha256:0:12}"
fi
log_dir="${log_dir:-$scratch/logs/$label_dir}"
mkdir -p "$log_dir"

# 3. The swap: rename (never copy over: the real file is a hard link of its deps/ twin).
mv "$real_bin" "$backup"
touch -d '1970-01-02' "$candidate"
mv "$candidate" "$real_bin"

results="$log_dir/results.jsonl"
: >"$results"
for entry in "${executables[@]}"; do
    name="${entry%%$'\t'*}"
    exe="${entry#*$'\t'}"
    if ! grep -qaF "$real_bin" "$exe"; then
        say "$name does not run $real_bin (its tests run anyway: they should pass on both)"
    fi
    mapfile -t all < <("$exe" --list --format terse | sed -n 's/: test$//p')
    mapfile -t ignored < <("$exe" --list --format terse --ignored | sed -n 's/: test$//p')
    for test in "${all[@]}"; do
        if printf '%s\n' "${ignored[@]}" | grep -qxF -- "$test" || ! selected "$name" "$test"; then
            continue
        fi
        log="$log_dir/${name}__${test//::/__}.log"
        say "$name::$test ..."
        start=$(date +%s.%N)
        # A temporary directory of its own, with /tmp's mode (other_users gives files to another
        # user through it), removed after the test: an old binary may write without end until
        # the timeout kills the test before it removes its own files (a replay wrote 8 GB).
        # A short name: tests make their bus directories in it, whose path must leave room for
        # the bus's unix sockets (48 bytes at most; load.rs's is `load-bus` and six more).
        test_tmp="$(mktemp -d "${TMPDIR:-/tmp}/cs-against.XXXXXX")"
        chmod 1777 "$test_tmp"
        # In the package directory, as cargo runs its tests. `--nocapture`: a test killed at the
        # timeout keeps what it printed so far in its log (the case it hung at), which the
        # harness would otherwise hold back until the test ends.
        (cd "$repo" && TMPDIR="$test_tmp" exec timeout --kill-after=10 "$per_test_timeout" \
            "$exe" --exact "$test" --test-threads=1 --nocapture) >"$log" 2>&1 &
        current_pid=$!
        rc=0
        wait "$current_pid" || rc=$?
        current_pid=""
        reap "$test_tmp"
        rm -rf "$test_tmp"
        test_tmp=""
        seconds=$(python3 -c "import sys; print(round($(date +%s.%N) - $start, 1))")
        # The summary line, not the test's own line: a test's child processes may write
        # between its name and its `ok`.
        if ((rc == 0)) && grep -q '^test result: ok\. 1 passed;' "$log"; then
            outcome=passed
        elif ((rc == 124 || rc == 137)); then
            outcome=timeout
        else
            outcome=failed
        fi
        python3 - "$name::$test" "$label" "$sha256" "$outcome" "$seconds" "$log" <<'PY' | tee -a "$results"
import json, sys
test, binary, sha, outcome, seconds, log = sys.argv[1:]
print(json.dumps({"test": test, "binary": binary, "sha256": sha, "passed": outcome == "passed",
                  "outcome": outcome, "seconds": float(seconds), "log": log}))
PY
    done
done

cleanup

# 4. The table.
python3 - "$results" "$label" >&2 <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
width = max(len(r["test"]) for r in rows)
print(f"\nagainst {sys.argv[2]}:")
for r in rows:
    print(f"  {r['test']:<{width}}  {r['outcome']:<7}  {r['seconds']:7.1f} s")
passed = sum(r["passed"] for r in rows)
print(f"  {passed} passed, {len(rows) - passed} failed or timed out, of {len(rows)}; "
      f"JSON lines also in {sys.argv[1]}")
PY
