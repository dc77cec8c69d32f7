import sys

from rheo_ros.app.cli import main

sys.exit(main())
