"""Does MAVSDK's own telemetry subscription hold memory per message? (the companion's memory growth)

    python benchmarks/mavsdk_odometry_memory.py [--seconds 80] [--speed-factor 5]

Starts a sitl-plant (loopback, free ports, its own process group, stopped on exit) and, in this
process, a MAVSDK 4.x companion connection to it, twice: once with no subscription, once
subscribed to odometry (the plant streams it at 50 Hz of simulated time, as the companion asks
PX4 to). Prints this process's resident memory (VmRSS) every 20 s of wall time and the growth per
1000 odometry messages. Linux only (/proc). Found on 2026-11-29 with mavsdk 4.1.0: flat without
the subscription, about 190 bytes per odometry message with it, the same slope as the companion's
resident memory in the soak (docs/reproduction.md section 6.2).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time


def rss_kb() -> int:
    with open("/proc/self/status") as status:
        return int(next(line for line in status if line.startswith("VmRSS")).split()[1])


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


async def measure(port: int, subscribe: str, seconds: float) -> list[tuple[float, int, int]]:
    """(wall s, VmRSS kB, odometry messages so far) every 20 s; MAVSDK connected to the plant on `port`.
    subscribe: "none", "telemetry" (MAVSDK's odometry subscription), "raw" (MAVSDK's raw:// byte stream,
    ODOMETRY decoded by pymavlink) or "modes" (MAVSDK's flight-mode, armed, in-air and status-text subscriptions,
    which the companion keeps; the count is then of HEARTBEATs seen by the flight-mode subscription)."""
    from mavsdk.asyncio import ComponentType, Configuration, ForwardingOption, Mavsdk
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
    samples, count = [], [0]
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"udpin://127.0.0.1:{port}", ForwardingOption.OFF)
        raw = None
        if subscribe == "raw":
            os.environ.setdefault("MAVLINK20", "1")
            from pymavlink.dialects.v20 import common

            parser = common.MAVLink(None)
            parser.robust_parsing = True

            def on_bytes(packet: bytes) -> None:
                for message in parser.parse_buffer(bytes(packet)) or ():
                    if message.get_msgId() == common.MAVLINK_MSG_ID_ODOMETRY:
                        count[0] += 1

            await sdk.add_any_connection("raw://", ForwardingOption.ON)
            raw = sdk._mavsdk.subscribe_raw_bytes_to_be_sent(on_bytes)
        system = await sdk.first_autopilot(timeout_s=20)
        if system is None:
            raise RuntimeError("no autopilot heard")
        task = None
        if subscribe == "telemetry":
            telemetry = TelemetryAsync(system)

            async def follow() -> None:
                async for _ in telemetry.subscribe_odometry():
                    count[0] += 1

            task = asyncio.create_task(follow())
        elif subscribe == "modes":
            telemetry = TelemetryAsync(system)

            async def drain(stream, counted: bool) -> None:
                async for _ in stream:
                    if counted:
                        count[0] += 1

            tasks = [asyncio.create_task(drain(telemetry.subscribe_flight_mode(), True)),
                     asyncio.create_task(drain(telemetry.subscribe_armed(), False)),
                     asyncio.create_task(drain(telemetry.subscribe_in_air(), False)),
                     asyncio.create_task(drain(telemetry.subscribe_status_text(), False))]
            task = asyncio.gather(*tasks)
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            await asyncio.sleep(20.0)
            samples.append((round(time.monotonic() - start, 1), rss_kb(), count[0]))
            print(f"  subscribe={subscribe}: {samples[-1]}", flush=True)
        if task is not None:
            task.cancel()
        if raw is not None:
            sdk._mavsdk.unsubscribe_raw_bytes_to_be_sent(raw)
    return samples


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=80.0, help="wall seconds per case (default: %(default)s)")
    parser.add_argument("--speed-factor", type=float, default=5.0, help="the plant's speed factor (default: %(default)s)")
    parser.add_argument("--cases", nargs="+", choices=("none", "telemetry", "raw", "modes"),
                        default=["none", "telemetry", "raw", "modes"],
                        help="what to subscribe to (default: all three, one after another)")
    args = parser.parse_args()
    for subscribe in args.cases:
        port = free_udp_port()
        with tempfile.TemporaryDirectory() as logs:
            plant = subprocess.Popen([sys.executable, "-m", "sitl_plant.sitl", "--speed-factor", str(args.speed_factor),
                                      "--companion-port", str(port), "--gcs-port", str(free_udp_port()),
                                      "--duration", str(args.seconds * args.speed_factor + 60), "--quiet",
                                      "--log-dir", logs], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                     start_new_session=True)
            try:
                samples = asyncio.run(measure(port, subscribe, args.seconds))
            finally:
                os.killpg(plant.pid, signal.SIGTERM)
                plant.wait(10)
        (_, first_kb, first_n), (_, last_kb, last_n) = samples[0], samples[-1]
        per_1000 = (last_kb - first_kb) / max(last_n - first_n, 1) * 1000 if subscribe != "none" else float("nan")
        print(f"subscribe={subscribe}: VmRSS {first_kb} -> {last_kb} kB over {samples[-1][0] - samples[0][0]:.0f} s; "
              f"{last_n - first_n} messages counted; {per_1000:.0f} kB per 1000 of them", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
