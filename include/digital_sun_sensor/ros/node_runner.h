// The two thin front ends of every node class (constructed from a public and
// a private node handle): a node executable's main() and a nodelet. A
// constructor that throws (bad parameter or config) ends the node with a
// FATAL message naming the problem.
#pragma once

#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include <memory>
#include <string>

namespace dss {

template <class Node>
int runNode(int argc, char** argv, const std::string& default_name) {
  ros::init(argc, argv, default_name);
  try {
    Node node(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("%s: %s", ros::this_node::getName().c_str(), e.what());
    return 1;
  }
  return 0;
}

template <class Node>
class NodeletFor : public nodelet::Nodelet {
 private:
  void onInit() override {
    try {
      node_ = std::make_unique<Node>(getNodeHandle(), getPrivateNodeHandle());
    } catch (const std::exception& e) {
      NODELET_FATAL("%s", e.what());
    }
  }
  std::unique_ptr<Node> node_;
};

}  // namespace dss
