"""``ncs-design`` command line: ``ncs-design serve`` starts the service."""

from __future__ import annotations

import argparse
import sys


LOOPBACK = ("127.0.0.1", "::1", "localhost")


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
    parser = argparse.ArgumentParser(prog="ncs-design", description="Networked predictive controller design service")
    sub = parser.add_subparsers(dest="command", required=True)
    serve = sub.add_parser("serve", help="run the HTTP service (uvicorn); settings come from NCS_* variables")
    serve.add_argument("--host", default=None, help="bind address (default NCS_HOST or 127.0.0.1)")
    serve.add_argument("--port", type=int, default=None, help="port (default NCS_PORT or 8000)")
    serve.add_argument("--log-level", default="info")
    sub.add_parser("migrate", help="apply the database migrations and exit")
    args = parser.parse_args(argv)

    from app.compute.process import limit_blas_threads

    limit_blas_threads()  # before numpy is imported: the request threads build plant families too
    from app.settings import Settings

    settings = Settings()
    if args.command == "migrate":
        from app.jobs.database import run_migrations

        run_migrations(settings.database_url, settings.alembic_dir)
        print(f"database at {settings.database_url} is up to date")
        return 0

    import uvicorn

    from app.main import create_app

    host = args.host or settings.host
    port = args.port if args.port is not None else settings.port
    print(access_notice(settings.api_keys, host), file=sys.stderr, flush=True)
    uvicorn.run(create_app(settings), host=host, port=port, log_level=args.log_level,
                timeout_graceful_shutdown=10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
