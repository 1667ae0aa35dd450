"""Stock ROS 2 nodes on the swarm (issue 19): Fast DDS profiles generated from the bundle."""
