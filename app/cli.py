"""``ncs-design`` command line.

``ncs-design serve`` starts the service, ``ncs-design migrate`` migrates its database;
``ncs-design design``, ``analyze`` and ``simulate`` work on plant files, in-process (the library,
no service needed) or against a service with ``--server URL``.

Exit codes: 0 success (stabilized, certified stable); 1 a valid problem without that answer
(infeasible, not converged, not certified); 2 bad usage or input (one line on stderr, no traceback);
3 the service or the solver failed.
"""

from __future__ import annotations

import argparse
import os
import sys


LOOPBACK = ("127.0.0.1", "::1", "localhost")
TOOL_COMMANDS = ("design", "analyze", "simulate", "codegen", "export-sdpa", "channel")


def package_version() -> str:
    """The installed distribution's version (``ncs-design --version``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ncs-design")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ncs-design", description="Design and certify networked predictive controllers for switched plants.",
        epilog="Exit codes: 0 ok; 1 infeasible / not converged / not certified; 2 bad usage or input; "
               "3 service or solver failure.")
    parser.add_argument("--version", action="version", version=f"ncs-design {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    serve = sub.add_parser("serve", help="run the HTTP service (uvicorn); settings come from NCS_* variables")
    serve.add_argument("--host", default=None, help="bind address (default NCS_HOST or 127.0.0.1)")
    serve.add_argument("--port", type=int, default=None, help="port (default NCS_PORT or 8000)")
    serve.add_argument("--log-level", default="info")
    sub.add_parser("migrate", help="apply the database migrations and exit")

    def plant_args(p):
        p.add_argument("plant", metavar="PLANT", help="plant file: the service's plant JSON (or a request "
                       "with a \"plant\"), or a .mat file with A/B (continuous) or F/G (discrete), each "
                       "n x k x r (M(:,:,l) is mode l), a cell array {M1, M2, ...} or one matrix")
        p.add_argument("--sampling-period", type=float, default=None, metavar="H",
                       help="sampling period in seconds (for A/B .mat files without h; overrides the file)")
        p.add_argument("--server", default=None, metavar="URL",
                       help="run on this ncs-design service instead of in-process")
        p.add_argument("--api-key", default=os.environ.get("NCS_API_KEY"),
                       help="the service's API key (default $NCS_API_KEY)")

    def gains_args(p):
        p.add_argument("--gains", required=True, metavar="FILE",
                       help="gains: a JSON design result or list (n_drop x m x n), or a .mat with K or K1..KN")
        p.add_argument("--n-drop", type=int, default=None, help="drop bound (default: the number of gains)")

    def network_args(p):
        p.add_argument("--network", default=None, metavar="SPEC",
                       help="the network: drops:N, delays:MAX_DELAY,N[,MIN_DELAY] (late, out-of-order packets) or "
                            "weakly_hard:MISSES,WINDOW,N; join with & for both (its N is the drop bound)")

    def performance_args(p):
        p.add_argument("--weights", default=None, metavar="JSON",
                       help='cost weights, inline or @file: {"Q": [[...]], "R": [[...]]}')
        p.add_argument("--x0", dest="perf_x0", default=None, metavar="X1,X2,...",
                       help="initial state of the cost bound (and inside the input-limit set)")
        p.add_argument("--disturbance", default=None, metavar="JSON",
                       help="E (n x p_w) or one per plant mode, inline or @file (hinf)")
        p.add_argument("--performance-output", default=None, metavar="JSON",
                       help='z = C x + D u, inline or @file: {"C": [[...]], "D": [[...]]} (default z = [x; u])')

    d = sub.add_parser("design", help="design gains K_1..K_N for a plant file")
    plant_args(d)
    d.add_argument("--n-drop", type=int, default=None,
                   help="at most n_drop - 1 consecutive losses (required unless PLANT is a request file with one, "
                        "or --network gives it)")
    d.add_argument("--method", default=None, help="design method: lmi (one SDP, default), ccl, ...")
    d.add_argument("--solver", choices=("AUTO", "IPM", "CLARABEL", "SCS"), type=str.upper, default=None,
                   help="SDP solver (default AUTO: the fastest with the same verdicts)")
    d.add_argument("--decay-rate", default=None, metavar="LAMBDA",
                   help="default 'auto' (settling within ~1.5x the fastest certifiable loop); a per-sample decay "
                        "rate in (0, 1]; 'max' for the smallest; 'none' for plain stability")
    d.add_argument("--plant-switching", choices=("per_interval", "per_sample"), default=None)
    d.add_argument("--scheme", choices=("predictive", "hold", "zero"), default=None)
    d.add_argument("--output", "-o", default=None, metavar="FILE",
                   help="write gains and certificate: .json (the service's result), .mat or .m (MATLAB/Octave)")
    d.add_argument("--objective", choices=("stability", "cost", "hinf"), default=None,
                   help="cost: minimize the certified worst-case quadratic cost; hinf: the certified l2 gain")
    d.add_argument("--u-max", default=None, metavar="U1,U2,...", help="input limits (one per input)")
    d.add_argument("--feedback", choices=("state", "output"), default=None,
                   help="output: measure y = C x (the plant file's \"C\") over a lossy sensor link, with an observer")
    d.add_argument("--sensor-n-drop", type=int, default=None,
                   help="with --feedback output: at most this minus one lost measurements in a row (default --n-drop)")
    d.add_argument("--observer", choices=("per_mode", "common"), default=None,
                   help="with --feedback output: one observer gain per plant mode (default) or one for all")
    network_args(d)
    performance_args(d)

    a = sub.add_parser("analyze", help="certify given gains (Theorem 1) and report spectral radii")
    plant_args(a)
    gains_args(a)
    performance_args(a)
    a.add_argument("--plant-switching", choices=("per_interval", "per_sample"), default=None)
    network_args(a)
    a.add_argument("--output", "-o", default=None, metavar="FILE.json", help="write the report as JSON")

    m = sub.add_parser("simulate", help="seeded simulation of given gains with packet losses")
    plant_args(m)
    gains_args(m)
    m.add_argument("--x0", default=None, help="initial state, comma-separated (default all ones)")
    m.add_argument("--steps", type=int, default=100)
    m.add_argument("--seed", type=int, default=42)
    m.add_argument("--plant-switching", choices=("per_interval", "per_sample", "none"), default="per_interval")
    m.add_argument("--mode", type=int, default=None, help="fixed plant mode (0-based) with --plant-switching none")
    network_args(m)
    m.add_argument("--plot", default=None, metavar="FILE", help="draw the run: .png or .svg")
    m.add_argument("--output", "-o", default=None, metavar="FILE.json", help="write the run as JSON")
    g = sub.add_parser("codegen", help="C99 code of the controller and the actuator's buffer for given gains")
    g.add_argument("result", metavar="RESULT", help="gains: a JSON design result (of `design -o` or a job) or "
                   "list (n_drop x m x n), or a .mat with K or K1..KN")
    g.add_argument("--out", required=True, metavar="DIR", help="directory to write <prefix>_controller.h/.c to")
    g.add_argument("--n-drop", type=int, default=None, help="drop bound (default: the number of gains)")
    g.add_argument("--exhausted", choices=("hold", "zero"), default="hold",
                   help="input once the newest packet is n_drop or more samples old (default hold)")
    g.add_argument("--prefix", default="ncs", help="prefix of the C names and files (default ncs)")
    g.add_argument("--precision", choices=("float64", "float32"), default="float64",
                   help="C arithmetic: double (default) or float, certified on the rounded gains (needs --plant)")
    g.add_argument("--plant", default=None, metavar="PLANT",
                   help="the design's plant file: for --precision float32 and the kit's replay test (test/)")
    g.add_argument("--sampling-period", type=float, default=None, metavar="H",
                   help="sampling period for A/B .mat plant files")

    x = sub.add_parser("export-sdpa", help="the SDP that design solves, in SDPA sparse format (.dat-s)")
    plant_args(x)
    x.add_argument("--n-drop", type=int, required=True, help="at most n_drop - 1 consecutive losses")
    x.add_argument("--method", default="lmi", help="lmi (default) or switched")
    x.add_argument("--decay-rate", default=None, metavar="LAMBDA", help="the SDP at this decay rate in (0, 1]")
    x.add_argument("--plant-switching", choices=("per_interval", "per_sample"), default=None)
    x.add_argument("--scheme", choices=("predictive", "hold", "zero"), default=None)
    x.add_argument("--output", "-o", default=None, metavar="FILE.dat-s", help="write here (default: stdout)")

    ch = sub.add_parser("channel", help="given gains on a lossy channel: how often the drop bound breaks, "
                        "mean-square stability, expected cost (in-process)")
    ch.add_argument("plant", metavar="PLANT", help="plant file (as for design)")
    ch.add_argument("--sampling-period", type=float, default=None, metavar="H")
    ch.add_argument("--gains", default=None, metavar="FILE",
                    help="gains: a JSON design result or list (n_drop x m x n), or a .mat with K or K1..KN")
    ch.add_argument("--n-drop", type=int, default=None, help="buffer length (default: the number of gains)")
    link = ch.add_mutually_exclusive_group(required=True)
    link.add_argument("--loss", type=float, default=None, metavar="P", help="Bernoulli loss probability per sample")
    link.add_argument("--gilbert-elliott", default=None, metavar="P_GB,P_BG,LOSS_GOOD,LOSS_BAD",
                      help="Gilbert-Elliott link: transition and loss probabilities per sample")
    link.add_argument("--channel", dest="channel_file", default=None, metavar="FILE.json",
                      help='channel JSON: {"kind": "markov", "transition": [[...]], "loss": [...]} (or bernoulli, '
                           "gilbert_elliott)")
    ch.add_argument("--delays", default=None, metavar="P0,P1,...",
                    help="per-packet delay distribution: P(a packet that arrives is a samples late), a = 0, 1, ...; "
                         "late packets are applied with their age (newest stamp wins)")
    ch.add_argument("--network", default=None, metavar="SPEC",
                    help="also report how often the channel breaks this network (drops:N, delays:D,N, "
                         "weakly_hard:M,K,N)")
    ch.add_argument("--exhausted", choices=("hold", "zero"), default="hold",
                    help="input once the buffer runs dry (default hold)")
    ch.add_argument("--no-cost", action="store_true", help="skip the expected cost (weights Q = I, R = I)")
    ch.add_argument("--design", action="store_true",
                    help="design gains for this channel instead (--gains is then optional; n_drop from --n-drop or "
                         "the gains file): minimal expected-cost bound, verdict by the analysis")
    ch.add_argument("--target-per-hour", type=float, default=None, metavar="RATE",
                    help="also print the smallest n_drop with at most RATE bursts per hour")
    ch.add_argument("--plot", default=None, metavar="FILE", help="violation rate vs n_drop and cost vs loss: .png/.svg")
    ch.add_argument("--output", "-o", default=None, metavar="FILE.json", help="write the report as JSON")
    return parser


def access_notice(api_keys: list[str], host: str) -> str:
    """The line ``serve`` prints at start: who can reach the service (never the keys themselves)."""
    if api_keys:
        return (f"ncs-design: API keys configured ({len(api_keys)}): /v1 requires X-API-Key or "
                f"Authorization: Bearer; binding to {host}")
    if host in LOOPBACK or host.startswith("127."):
        return (f"ncs-design: no API keys configured (NCS_API_KEYS): authentication is off, so the service "
                f"binds to loopback only ({host}); set NCS_API_KEYS before binding to another address")
    return (f"ncs-design: WARNING: no API keys configured (NCS_API_KEYS) and binding to {host}: anyone who "
            f"can reach this address can submit jobs and read every job")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in TOOL_COMMANDS:
        import warnings

        # numpy's overflow and conversion warnings from a badly scaled plant repeat per iteration: the verdict
        # and its message say what went wrong, so the terminal gets each warning once at most.
        warnings.simplefilter("once")
        from app.cli_commands import run_command

        return run_command(args)

    from app.compute.process import limit_blas_threads

    limit_blas_threads()  # before numpy is imported: the request threads build plant families too
    from app.settings import Settings

    settings = Settings()
    from app.jobs.database import DatabaseSettingError, check_database_url

    try:  # a wrong NCS_DATABASE_URL is one line naming the setting and the cause, not a traceback
        check_database_url(settings.database_url, settings.alembic_dir)
    except DatabaseSettingError as exc:
        print(f"ncs-design {args.command}: {exc}", file=sys.stderr)
        return 2
    if args.command == "migrate":
        print(f"database at {settings.database_url} is up to date")
        return 0

    import uvicorn

    from app.main import create_app

    host = args.host or settings.host
    port = args.port if args.port is not None else settings.port
    print(access_notice(settings.api_keys, host), file=sys.stderr, flush=True)
    uvicorn.run(create_app(settings), host=host, port=port, log_level=args.log_level,
                timeout_graceful_shutdown=10, timeout_keep_alive=settings.keep_alive)
    return 0


if __name__ == "__main__":
    sys.exit(main())
