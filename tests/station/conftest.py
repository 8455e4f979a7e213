"""Shared fixtures of the station tests: a real PostgreSQL server for the archive index."""

import pytest
import qh_pg
import qh_required


@pytest.fixture(scope="session")
def pg_server():
    """A throw-away PostgreSQL server (pg_ctl) for the whole session, stopped at the end.

    Fails the tests that use it with one line when it is installed but cannot start, or is
    missing under ``make test``/CI/root; skips only on a developer's machine without it.
    """
    srv = qh_pg.PgServer()
    try:
        srv.start()
    except (qh_pg.PgUnavailable, OSError) as exc:
        if srv.bin is not None:  # installed but cannot start: always a failure
            pytest.fail(str(exc), pytrace=False)
        qh_required.unavailable(str(exc))
    yield srv
    srv.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def index_url(request):
    """None (the archive's own SQLite file) or a fresh PostgreSQL database's URL."""
    if request.param == "sqlite":
        return None
    return request.getfixturevalue("pg_server").new_database()
