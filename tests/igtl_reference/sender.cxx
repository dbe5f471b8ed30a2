// Reference OpenIGTLink sender on the OpenIGTLink C++ library: a server that streams, at 20 Hz,
// a known MarkerToTracker pose and a ReferenceToTracker in one of three forms (TRANSFORM,
// POSITION, TDATA), leaving the marker out of every 4th frame the way PLUS does for a tool it
// does not see.
//
//     igtl_reference_sender PORT transform|position|tdata
//
// Prints "READY" once listening; serves one client until it disconnects.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "igtlOSUtil.h"
#include "igtlPositionMessage.h"
#include "igtlServerSocket.h"
#include "igtlTimeStamp.h"
#include "igtlTrackingDataMessage.h"
#include "igtlTransformMessage.h"

// The marker pose the tests expect: 30 deg about z, then (12.5, -40, -1450) mm.
static void markerMatrix(igtl::Matrix4x4& m) {
  const float c = std::cos(M_PI / 6.0), s = std::sin(M_PI / 6.0);
  igtl::IdentityMatrix(m);
  m[0][0] = c; m[0][1] = -s;
  m[1][0] = s; m[1][1] = c;
  m[0][3] = 12.5f; m[1][3] = -40.0f; m[2][3] = -1450.0f;
}

static void referenceMatrix(igtl::Matrix4x4& m) {
  igtl::IdentityMatrix(m);
  m[0][3] = 100.0f; m[1][3] = 0.0f; m[2][3] = -1300.0f;
}

static int sendTransform(igtl::Socket* socket, const char* name, igtl::Matrix4x4& m, igtl::TimeStamp::Pointer& ts) {
  igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
  message->SetDeviceName(name);
  message->SetMatrix(m);
  message->SetTimeStamp(ts);
  message->Pack();
  return socket->Send(message->GetPackPointer(), message->GetPackSize());
}

static int sendPosition(igtl::Socket* socket, const char* name, igtl::Matrix4x4& m, igtl::TimeStamp::Pointer& ts) {
  float q[4];
  igtl::MatrixToQuaternion(m, q);  // (ox, oy, oz, w)
  igtl::PositionMessage::Pointer message = igtl::PositionMessage::New();
  message->SetDeviceName(name);
  message->SetPackType(igtl::PositionMessage::ALL);
  message->SetPosition(m[0][3], m[1][3], m[2][3]);
  message->SetQuaternion(q);
  message->SetTimeStamp(ts);
  message->Pack();
  return socket->Send(message->GetPackPointer(), message->GetPackSize());
}

int main(int argc, char* argv[]) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s PORT transform|position|tdata\n", argv[0]);
    return 2;
  }
  const int port = std::atoi(argv[1]);
  const std::string form = argv[2];
  igtl::ServerSocket::Pointer server = igtl::ServerSocket::New();
  if (server->CreateServer(port) < 0) {
    std::fprintf(stderr, "cannot listen on %d\n", port);
    return 1;
  }
  std::printf("READY\n");
  std::fflush(stdout);
  igtl::Socket::Pointer socket;
  while (!socket.IsNotNull()) socket = server->WaitForConnection(1000);
  igtl::Matrix4x4 marker, reference;
  markerMatrix(marker);
  referenceMatrix(reference);
  igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
  for (int frame = 0;; ++frame) {
    ts->GetTime();
    const bool seen = frame % 4 != 3;
    int ok = 1;
    if (form == "tdata") {
      igtl::TrackingDataMessage::Pointer message = igtl::TrackingDataMessage::New();
      message->SetDeviceName("Tracker");
      if (seen) {
        igtl::TrackingDataElement::Pointer element = igtl::TrackingDataElement::New();
        element->SetName("MarkerToTracker");
        element->SetType(igtl::TrackingDataElement::TYPE_6D);
        element->SetMatrix(marker);
        message->AddTrackingDataElement(element);
      }
      igtl::TrackingDataElement::Pointer element = igtl::TrackingDataElement::New();
      element->SetName("ReferenceToTracker");
      element->SetType(igtl::TrackingDataElement::TYPE_6D);
      element->SetMatrix(reference);
      message->AddTrackingDataElement(element);
      message->SetTimeStamp(ts);
      message->Pack();
      ok = socket->Send(message->GetPackPointer(), message->GetPackSize());
    } else {
      auto send = form == "position" ? sendPosition : sendTransform;
      if (seen) ok = send(socket, "MarkerToTracker", marker, ts);
      if (ok) ok = send(socket, "ReferenceToTracker", reference, ts);
    }
    if (!ok) break;  // the client went away
    igtl::Sleep(50);
  }
  socket->CloseSocket();
  return 0;
}
