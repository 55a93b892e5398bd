// Reading a namespace of ROS parameters (as rosparam holds it: an XmlRpc
// struct) into config structs, in one place for the server and the device:
// typed reads that keep the in-class default when a key is absent, errors
// naming the parameter on a wrong type, and the keys nobody read (misspelt or
// unknown). Testable without a ROS master (feed it a struct built from YAML).
//
//   ParamReader r(params, "~");                 // or "/edge_server/"
//   r.read("every", &config.every);
//   ParamReader t = r.child("tracking");        // ~tracking/...
//   t.read("min_inliers", &config.tracker.min_inliers);
//   std::vector<std::string> unknown = r.unknown();  // "tracking/typo", ...
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <ros/node_handle.h>
#include <xmlrpcpp/XmlRpcValue.h>
#include <Eigen/Core>

namespace ecar_bridge {

class ParamReader {
 public:
  /// `params`: a struct of parameters (anything else reads as empty). `name`
  /// prefixes the keys in error texts, e.g. "~" or "/edge_server/".
  ParamReader(const XmlRpc::XmlRpcValue& params, const std::string& name);

  /// Each leaves *value unchanged when the key is absent and throws
  /// ecar::Error ("<name><key>: expected <type>") when it has another type.
  void read(const std::string& key, std::string* value);
  void read(const std::string& key, bool* value);
  void read(const std::string& key, int* value);
  /// Integers are accepted too.
  void read(const std::string& key, double* value);
  void read(const std::string& key, float* value);
  /// An integer >= 0.
  void read(const std::string& key, uint32_t* value);
  void read(const std::string& key, size_t* value);
  /// A list of three numbers.
  void read(const std::string& key, Eigen::Vector3d* value);

  /// The reader of a nested struct (e.g. "tracking"); its keys are reported
  /// by this reader's unknown() too. Throws when the key is not a struct.
  ParamReader& child(const std::string& key);

  /// Keys present but not read, here and in the children (nested ones joined
  /// with '/'), e.g. "tracking/typo".
  std::vector<std::string> unknown() const;

 private:
  const XmlRpc::XmlRpcValue* find(const std::string& key);
  [[noreturn]] void fail(const std::string& key, const std::string& type) const;

  XmlRpc::XmlRpcValue params_;
  std::string name_;    ///< for errors
  std::string prefix_;  ///< of this reader's keys within the root, for unknown()
  std::vector<std::string> used_;
  std::vector<std::unique_ptr<ParamReader>> children_;
};

/// The struct of parameters under `nh`'s namespace (empty when none).
XmlRpc::XmlRpcValue paramsOf(const ros::NodeHandle& nh);

/// A YAML parameter file as `rosparam load` would hold it (maps as structs,
/// sequences as arrays, scalars as bool, int, double or string), e.g. to check
/// a shipped config file without a ROS master. Throws ecar::Error naming the
/// file when it cannot be read or parsed.
XmlRpc::XmlRpcValue paramsFromYaml(const std::string& path);

}  // namespace ecar_bridge
