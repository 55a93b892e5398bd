// ecar_msgs <-> ecar_core for structure and user interaction: planes, virtual
// objects, interactions and their answers, touches.
//
// Readers check what they read (finite coordinates, known enum values) and
// throw ecar::Error naming the field (e.g. "objects[2].start: non-finite
// value"); `field` prefixes the name for elements of arrays.
#pragma once

#include <string>

#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/Plane.h>
#include <ecar_msgs/Touch.h>
#include <ecar_msgs/VirtualObject.h>
#include <std_msgs/Header.h>

#include "ecar_core/common/touch.h"
#include "ecar_core/structure/plane.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar_bridge {

/// Field for field (boundary as points).
ecar_msgs::Plane toMsg(const ecar::Plane& plane);
/// Throws on a non-finite value, a normal that is not unit (within 1e-3) or a
/// label beyond OTHER.
ecar::Plane fromMsg(const ecar_msgs::Plane& msg, const std::string& field = "plane");

/// Field for field.
ecar_msgs::VirtualObject toMsg(const ecar::VirtualObject& vo);
/// Throws on a non-finite coordinate or normal, a zero normal, a width that is
/// not finite and >= 0, or a kind other than LINE / ANCHOR.
ecar::VirtualObject fromMsg(const ecar_msgs::VirtualObject& msg,
                            const std::string& field = "object");

/// The Interaction of a request (device_id from the request; header as given).
ecar_msgs::Interaction toMsg(const ecar::VoRequest& request, const std_msgs::Header& header);
/// Throws on a type beyond DELETE or a bad object (not read for DELETE).
ecar::VoRequest fromMsg(const ecar_msgs::Interaction& msg);

/// The InteractionResult of an answer (device_id from the result).
ecar_msgs::InteractionResult toMsg(const ecar::VoResult& result, const std_msgs::Header& header);
ecar::VoResult fromMsg(const ecar_msgs::InteractionResult& msg);

/// The touch's pixel, phase, colour and width; `header` as given.
ecar_msgs::Touch toMsg(const ecar::Touch& touch, const std_msgs::Header& header);
/// Throws on a non-finite pixel, a width that is not finite and > 0, or a
/// phase beyond END.
ecar::Touch fromMsg(const ecar_msgs::Touch& msg);

}  // namespace ecar_bridge
