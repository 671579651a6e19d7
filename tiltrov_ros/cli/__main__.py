"""``python -m tiltrov_ros.cli``: the ``tiltrov`` command."""

import sys

from tiltrov_ros.cli import main

sys.exit(main())
