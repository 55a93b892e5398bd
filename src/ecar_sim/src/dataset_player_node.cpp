// dataset_player: publishes a dataset folder as one device's camera.
// See dataset_player.h for the topics and parameters, and launch/player.launch.
#include <ros/ros.h>

#include "dataset_player.h"
#include "ecar_core/common/error.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "dataset_player");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  try {
    ecar_sim::DatasetPlayer player(nh, ecar_sim::loadDatasetPlayerConfig(pnh));
    player.run();
    // Stay up so that the latched `finished` message remains available.
    if (ros::ok()) ros::spin();
  } catch (const ecar::Error& e) {
    ROS_FATAL("%s: %s", ros::this_node::getName().c_str(), e.what());
    return 1;
  }
  return 0;
}
