"""`python -m map_consistency_ros.ros`: the live node."""
import sys

from map_consistency_ros.ros.node import main

sys.exit(main())
