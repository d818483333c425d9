"""Markers of the pytest suite: CTest runs the command-line tests (`-m cli`), the web viewer's (`-m web`) and the
Python module tests (`-m "not cli and not web"`) as three entries, so a failure shows which of them broke."""


def pytest_configure(config):
    config.addinivalue_line("markers", "cli: drives the sfgs executable as a user would (CTest entry 'cli')")
    config.addinivalue_line("markers", "web: the web viewer in headless Chromium (CTest entry 'web')")
