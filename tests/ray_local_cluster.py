"""A real local Ray cluster on 127.0.0.1 for the tests: a head (no CPUs, so work goes to the workers) and N
worker nodes, each its own raylet and object store, started with Ray's own multi-node test harness
(ray.cluster_utils.Cluster, the documented way to simulate a multi-node cluster on one machine).

`ray start` cannot do this on loopback: Ray replaces 127.0.0.1 with the machine's network address unless
RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, and with that set `ray start --address` refuses to add a worker node.

Run as a process: `python tests/ray_local_cluster.py --workers 2 --cpus 1 --temp-dir DIR` prints one JSON line
{"address", "nodes": [{"node_id", "pids"}]} and keeps the cluster up until SIGTERM / SIGINT, then shuts every
process of it down. Tests start it, read the line, and stop it by its process id.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cpus", type=float, default=1)
    parser.add_argument("--temp-dir", default=None)
    parser.add_argument("--client-port", type=int, default=None, help="also serve Ray Client (ray://) on this port")
    args = parser.parse_args()
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"  # every node on 127.0.0.1, nothing on the network
    from ray.cluster_utils import Cluster

    head_args = {"num_cpus": 0, "include_dashboard": False, "object_store_memory": 200 << 20}
    if args.client_port:
        head_args["ray_client_server_port"] = args.client_port
    if args.temp_dir:  # sessions, sockets and the "current cluster" file stay in the test's folder
        os.makedirs(os.path.join(args.temp_dir, "ray"), exist_ok=True)
        os.environ["RAY_TMPDIR"] = args.temp_dir
        head_args["temp_dir"] = args.temp_dir
    cluster = Cluster(initialize_head=True, head_node_args=head_args)
    nodes = [cluster.add_node(num_cpus=args.cpus, object_store_memory=200 << 20) for _ in range(args.workers)]
    cluster.wait_for_nodes()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    info = {"address": cluster.address, "client_address": f"ray://127.0.0.1:{args.client_port}" if args.client_port else None,
            "nodes": [{"node_id": n.node_id, "pids": [p.process.pid for procs in n.all_processes.values()
                                                        for p in procs]} for n in nodes]}
    print(json.dumps(info), flush=True)
    stop.wait()
    cluster.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
