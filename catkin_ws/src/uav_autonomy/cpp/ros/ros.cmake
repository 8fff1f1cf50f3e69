# The roscpp node (included from ../CMakeLists.txt inside the catkin build of uav_autonomy).
find_package(catkin REQUIRED COMPONENTS roscpp sensor_msgs nav_msgs visualization_msgs std_msgs std_srvs
  geometry_msgs tf2 tf2_ros octomap_msgs uav_msgs message_filters)

add_executable(map_server ros/map_server_node.cpp ros/ros_conversions.cpp)
target_include_directories(map_server SYSTEM PRIVATE ${catkin_INCLUDE_DIRS})
target_compile_options(map_server PRIVATE ${UAV_MAP_CXX_FLAGS})
target_link_libraries(map_server uav_mapping_core ${catkin_LIBRARIES})
add_dependencies(map_server ${catkin_EXPORTED_TARGETS})
set_target_properties(map_server PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${UAV_MAP_BIN_DIR})
