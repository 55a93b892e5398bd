#include "ecar_bridge/params.h"

#include <algorithm>

#include <yaml-cpp/yaml.h>

#include "ecar_core/common/error.h"

namespace ecar_bridge {

ParamReader::ParamReader(const XmlRpc::XmlRpcValue& params, const std::string& name)
    : params_(params), name_(name) {}

const XmlRpc::XmlRpcValue* ParamReader::find(const std::string& key) {
  used_.push_back(key);
  if (params_.getType() != XmlRpc::XmlRpcValue::TypeStruct || !params_.hasMember(key)) {
    return nullptr;
  }
  return &params_[key];
}

void ParamReader::fail(const std::string& key, const std::string& type) const {
  throw ecar::Error(name_ + key + ": expected " + type);
}

void ParamReader::read(const std::string& key, std::string* value) {
  if (const XmlRpc::XmlRpcValue* v = find(key)) {
    if (v->getType() != XmlRpc::XmlRpcValue::TypeString) fail(key, "a string");
    *value = static_cast<std::string>(*const_cast<XmlRpc::XmlRpcValue*>(v));
  }
}

void ParamReader::read(const std::string& key, bool* value) {
  if (const XmlRpc::XmlRpcValue* v = find(key)) {
    if (v->getType() != XmlRpc::XmlRpcValue::TypeBoolean) fail(key, "a bool");
    *value = static_cast<bool>(*const_cast<XmlRpc::XmlRpcValue*>(v));
  }
}

void ParamReader::read(const std::string& key, int* value) {
  if (const XmlRpc::XmlRpcValue* v = find(key)) {
    if (v->getType() != XmlRpc::XmlRpcValue::TypeInt) fail(key, "an integer");
    *value = static_cast<int>(*const_cast<XmlRpc::XmlRpcValue*>(v));
  }
}

void ParamReader::read(const std::string& key, double* value) {
  if (const XmlRpc::XmlRpcValue* v = find(key)) {
    auto& x = *const_cast<XmlRpc::XmlRpcValue*>(v);
    if (x.getType() == XmlRpc::XmlRpcValue::TypeInt) {
      *value = static_cast<int>(x);
    } else if (x.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
      *value = static_cast<double>(x);
    } else {
      fail(key, "a number");
    }
  }
}

void ParamReader::read(const std::string& key, float* value) {
  double d = *value;
  read(key, &d);
  *value = static_cast<float>(d);
}

void ParamReader::read(const std::string& key, uint32_t* value) {
  int v = static_cast<int>(*value);
  read(key, &v);
  if (v < 0) fail(key, "an integer >= 0");
  *value = static_cast<uint32_t>(v);
}

void ParamReader::read(const std::string& key, size_t* value) {
  uint32_t v = static_cast<uint32_t>(*value);
  read(key, &v);
  *value = v;
}

void ParamReader::read(const std::string& key, Eigen::Vector3d* value) {
  if (const XmlRpc::XmlRpcValue* v = find(key)) {
    auto& x = *const_cast<XmlRpc::XmlRpcValue*>(v);
    if (x.getType() != XmlRpc::XmlRpcValue::TypeArray || x.size() != 3) {
      fail(key, "a list of 3 numbers");
    }
    for (int i = 0; i < 3; ++i) {
      if (x[i].getType() == XmlRpc::XmlRpcValue::TypeInt) {
        (*value)[i] = static_cast<int>(x[i]);
      } else if (x[i].getType() == XmlRpc::XmlRpcValue::TypeDouble) {
        (*value)[i] = static_cast<double>(x[i]);
      } else {
        fail(key, "a list of 3 numbers");
      }
    }
  }
}

ParamReader& ParamReader::child(const std::string& key) {
  used_.push_back(key);
  XmlRpc::XmlRpcValue nested;
  if (params_.getType() == XmlRpc::XmlRpcValue::TypeStruct && params_.hasMember(key)) {
    nested = params_[key];
    if (nested.getType() != XmlRpc::XmlRpcValue::TypeStruct) fail(key, "a map of parameters");
  }
  children_.push_back(std::make_unique<ParamReader>(nested, name_ + key + "/"));
  children_.back()->prefix_ = prefix_ + key + "/";
  return *children_.back();
}

std::vector<std::string> ParamReader::unknown() const {
  std::vector<std::string> out;
  if (params_.getType() == XmlRpc::XmlRpcValue::TypeStruct) {
    for (auto it = params_.begin(); it != params_.end(); ++it) {
      if (std::find(used_.begin(), used_.end(), it->first) == used_.end()) {
        out.push_back(prefix_ + it->first);
      }
    }
  }
  for (const auto& c : children_) {
    for (auto& k : c->unknown()) out.push_back(std::move(k));
  }
  return out;
}

XmlRpc::XmlRpcValue paramsOf(const ros::NodeHandle& nh) {
  XmlRpc::XmlRpcValue params;
  if (!nh.getParam(nh.getNamespace(), params) ||
      params.getType() != XmlRpc::XmlRpcValue::TypeStruct) {
    return XmlRpc::XmlRpcValue();
  }
  return params;
}

namespace {

XmlRpc::XmlRpcValue toXmlRpc(const YAML::Node& node) {
  if (node.IsMap()) {
    XmlRpc::XmlRpcValue v;
    v.begin();  // an empty struct, not an invalid value
    for (const auto& kv : node) v[kv.first.as<std::string>()] = toXmlRpc(kv.second);
    return v;
  }
  if (node.IsSequence()) {
    XmlRpc::XmlRpcValue v;
    v.setSize(static_cast<int>(node.size()));
    for (size_t i = 0; i < node.size(); ++i) v[static_cast<int>(i)] = toXmlRpc(node[i]);
    return v;
  }
  if (node.IsNull()) return XmlRpc::XmlRpcValue(std::string());
  const std::string s = node.as<std::string>();
  if (node.Tag() == "!" || s.empty()) return XmlRpc::XmlRpcValue(s);  // quoted string
  if (s == "true" || s == "false") return XmlRpc::XmlRpcValue(s == "true");
  try {
    size_t used = 0;
    const int i = std::stoi(s, &used);
    if (used == s.size()) return XmlRpc::XmlRpcValue(i);
    const double d = std::stod(s, &used);
    if (used == s.size()) return XmlRpc::XmlRpcValue(d);
  } catch (const std::exception&) {
  }
  return XmlRpc::XmlRpcValue(s);
}

}  // namespace

XmlRpc::XmlRpcValue paramsFromYaml(const std::string& path) {
  try {
    return toXmlRpc(YAML::LoadFile(path));
  } catch (const YAML::Exception& e) {
    throw ecar::Error(path + ": " + e.what());
  }
}

}  // namespace ecar_bridge
