#!/bin/sh
# launch-prefix for rostest files: runs the node (the rest of the command line) and writes its exit code to the
# file named by the first argument, so that a check node can see how the node under test ended.
#   <arg name="launch_prefix" value="$(find uav_rostests)/mapping/record_exit_code.sh /tmp/$(anon exit)"/>
out="$1"
shift
"$@"
code=$?
echo "$code" > "$out.tmp" && mv "$out.tmp" "$out"
exit "$code"
