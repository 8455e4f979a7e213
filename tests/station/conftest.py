"""Shared fixtures of the station tests: a real PostgreSQL server for the archive index."""

import os

import pytest
import qh_pg


def _must_run() -> bool:
    """In CI, or as root (``make test`` installs the server then), PostgreSQL may not skip."""
    return bool(os.environ.get("CI")) or os.geteuid() == 0


@pytest.fixture(scope="session")
def pg_server():
    """A throw-away PostgreSQL server (pg_ctl) for the whole session, stopped at the end.

    Fails the tests that use it with one line when it cannot start in CI or as root; skips
    only on a developer's machine without PostgreSQL.
    """
    srv = qh_pg.PgServer()
    try:
        srv.start()
    except (qh_pg.PgUnavailable, OSError) as exc:
        if _must_run() or srv.bin is not None:
            pytest.fail(str(exc), pytrace=False)
        pytest.skip(f"{exc} -- not CI and not root, so the PostgreSQL tests skip")
    yield srv
    srv.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def index_url(request):
    """None (the archive's own SQLite file) or a fresh PostgreSQL database's URL."""
    if request.param == "sqlite":
        return None
    return request.getfixturevalue("pg_server").new_database()
