"""Import the real `by_your_command` package before pytest collects any test.

With --import-mode=importlib, pytest names test modules after their path
(by_your_command.test.<dir>.<file>) and, when `by_your_command` is not imported yet, registers
an empty namespace module under that name which hides the real package.
"""

import by_your_command  # noqa: F401
