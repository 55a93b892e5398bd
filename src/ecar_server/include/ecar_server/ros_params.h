// The one place where the server's parameters are read from rosparam, and the
// process-wide global graph the nodelets of one manager share.
#pragma once

#include <exception>
#include <memory>
#include <string>
#include <vector>

#include <ros/console.h>
#include <ros/node_handle.h>

#include "ecar_core/common/timing.h"
#include "ecar_core/server/global_graph.h"
#include "ecar_server/config.h"

namespace ecar_server {

/// The server's config from a struct of parameters (as rosparam holds the
/// manager's namespace; config/server.yaml's layout), keeping the in-class
/// default for absent keys, validated. `name` prefixes keys in errors (e.g.
/// "/edge_server/"). The keys it does not know go to *unknown (nested ones
/// joined with '/'; may be null). Throws ecar::Error naming the key when a
/// value has the wrong type or range.
ServerConfig parseServerConfig(const XmlRpc::XmlRpcValue& params, const std::string& name,
                               std::vector<std::string>* unknown);

/// Reads the config from `nh` (the manager's namespace, e.g. /edge_server).
/// Throws ecar::Error naming the key as parseServerConfig does, and when the
/// namespace holds a key the server does not know (a misspelt key would
/// otherwise be ignored silently); the manager's own num_worker_threads, the
/// startup map_file and the nodelets' private namespaces are allowed.
ServerConfig loadServerConfig(const ros::NodeHandle& nh);

/// The global graph shared by the nodelets of one manager (`key`: its
/// namespace), created with `config` by the first caller (its map epoch starts
/// at the wall clock's milliseconds, so a restarted server has another);
/// later callers share it. It lives while someone holds it. Throws ecar::Error
/// when it cannot be created (e.g. the VO database cannot be opened).
std::shared_ptr<ecar::GlobalGraph> sharedGraph(const std::string& key, const ServerConfig& config);

/// Seconds on the steady clock (the registry's clock for device timeouts).
using ecar::steadySeconds;

/// Runs a nodelet's initialisation. nodelet's manager swallows an exception
/// thrown by onInit (its loader only says "Failed to load"), so this logs it as
/// FATAL, naming the nodelet and the reason (a bad parameter, a VO database
/// another server holds, ...), and rethrows so that the load fails.
template <typename Initialise>
void initialiseOrReport(const std::string& nodelet, Initialise initialise) {
  try {
    initialise();
  } catch (const std::exception& e) {
    ROS_FATAL("%s: cannot start: %s", nodelet.c_str(), e.what());
    throw;
  }
}

}  // namespace ecar_server
