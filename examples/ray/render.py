"""A sharded nerf-render on Ray: one Ray task per shard runs `nerf-render --shard i/n`, then the
merge assembles the GIF, metrics.json and contact sheet.

    python examples/ray/render.py --bundle models/spheres --out /tmp/spheres-orbit \
        --shards 4 -- --orbit --frames 40

With --address, or RAY_ADDRESS set (`ray start --head` prints the address; `auto` finds the
cluster `ray start` left on this machine; ray://host:10001 reaches a remote one through Ray
Client), the tasks go to that running cluster, whose nodes must all see --bundle and --out at
the same paths (a shared filesystem) and have nerf-render (--nerf-render) and onnxruntime.
Without either, a local Ray cluster is started for the run and stopped after it. Everything
after `--` is passed to nerf-render and says what to render (--orbit, --camera-path FILE,
--split test --data DIR, ...). A task that Ray retries keeps the frames its earlier attempt
finished (--skip-existing).
"""

import argparse
import os
import socket
import subprocess
import sys
import time

import ray


@ray.remote
def render_shard(command, index, count):
    """Run shard `index` of `count`: where it ran (host, Ray node id, worker pid), its seconds
    and nerf-render's summary."""
    start = time.time()
    done = subprocess.run([*command, "--shard", f"{index}/{count}", "--skip-existing"], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"shard {index}/{count} failed on {socket.gethostname()}:\n{done.stdout}{done.stderr}")
    node = ray.get_runtime_context().get_node_id()
    return socket.gethostname(), node, os.getpid(), time.time() - start, done.stdout.strip()


def reachable(address):
    """Exit with a message unless something listens at a host:port `address` (ray.init would
    retry a missing one for minutes). `auto` and ray:// addresses are left to Ray."""
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=10).close()
    except OSError as e:
        sys.exit(f"ray: no cluster at {address}: {e}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bundle", required=True, help="scene bundle directory (nerf export --out)")
    parser.add_argument("--out", required=True, help="output directory every node can write")
    parser.add_argument("--shards", type=int, default=4, help="how many shards (Ray tasks)")
    parser.add_argument("--threads", type=int, default=1, help="CPUs per shard (Ray num_cpus and nerf-render --threads)")
    parser.add_argument("--nerf-render", default="nerf-render", help="the nerf-render binary on the nodes")
    parser.add_argument("--address", default=os.environ.get("RAY_ADDRESS"), help="a running Ray cluster to use (default: $RAY_ADDRESS, else start a local one)")
    parser.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local cluster when one is started (default: all)")
    parser.add_argument("views", nargs=argparse.REMAINDER, help="-- then what to render (default: --orbit)")
    args = parser.parse_args()
    if args.shards < 1:
        parser.error("--shards must be at least 1")
    views = [v for v in args.views if v != "--"] or ["--orbit"]
    # Absolute paths: Ray's workers need not share this directory as theirs.
    bundle, out = os.path.abspath(args.bundle), os.path.abspath(args.out)
    binary = os.path.abspath(args.nerf_render) if os.sep in args.nerf_render else args.nerf_render
    command = [binary, "--bundle", bundle, "--out", out, "--threads", str(args.threads), *views]

    if args.address and args.address != "local":
        if args.num_cpus is not None:
            parser.error("--num-cpus sizes a local cluster; a running one (--address, RAY_ADDRESS) has its own")
        reachable(args.address)
        try:
            ray.init(address=args.address)
        except (ConnectionError, ValueError) as e:
            sys.exit(f"ray: no cluster at {args.address}: {e}")
        how = "joined the cluster at"
    else:
        # "local": a new cluster even where `ray start` left one that ray.init() would join.
        ray.init(address="local", num_cpus=args.num_cpus, include_dashboard=False)
        how = "started a local cluster at"
    nodes = sum(1 for n in ray.nodes() if n["Alive"])
    cpus = ray.cluster_resources().get("CPU", 0)
    print(f"ray: {how} {ray.get_runtime_context().gcs_address} ({nodes} nodes, {cpus:.0f} CPUs), driver pid {os.getpid()}", flush=True)
    print(f"ray: {args.shards} shards of: {' '.join(command)}", flush=True)
    start = time.time()
    tasks = [render_shard.options(num_cpus=args.threads).remote(command, i, args.shards) for i in range(args.shards)]
    # Every shard's result or failure (its message and nerf-render's output, not Ray's traceback).
    results, failed = [], []
    for task in tasks:
        try:
            results.append(ray.get(task))
        except ray.exceptions.RayTaskError as e:
            failed.append(str(e.cause))
    if failed:
        sys.exit("\n".join(failed))
    for i, (host, node, pid, seconds, summary) in enumerate(results):
        print(f"shard {i}/{args.shards} on {host} (node {node}, worker pid {pid}) in {seconds:.1f} s: {summary.splitlines()[0]}", flush=True)
    merged = subprocess.run([binary, "--merge", "--out", out], capture_output=True, text=True)
    if merged.returncode != 0:
        sys.exit(f"merge failed:\n{merged.stdout}{merged.stderr}")
    print(f"merged in {time.time() - start:.1f} s after the start of the shards:\n{merged.stdout.strip()}")


if __name__ == "__main__":
    main()
