import sys

from rheo_ros.cli import main

sys.exit(main())
