"""Markers of the pytest suite: CTest runs the command-line tests (`-m cli`) and the Python module tests
(`-m "not cli"`) as two entries, so a failure shows which of them broke."""


def pytest_configure(config):
    config.addinivalue_line("markers", "cli: drives the sfgs executable as a user would (CTest entry 'cli')")
