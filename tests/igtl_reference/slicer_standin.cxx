// A stand-in for 3D Slicer's OpenIGTLinkIF connector (client mode) on the OpenIGTLink C++
// library: it connects to spacecal, sends the needle plan the way Slicer sends a point list
// and a linear transform, then counts the TRANSFORM messages it receives.
//
//     igtl_reference_slicer PORT SECONDS [bad]
//
// 1. POINT "Plan": three control points as Slicer's vtkMRMLIGTLConnectorNode packs a markups
//    point list (name = label, group "Selected"/"Unselected", RGBA, position in RAS, radius 0):
//    "F-1" (-5, 6, 7), "entry" (12.5, -40.25, 7), "Target" (-31.75, 18.5, -102).
//    With "bad": the target's x is NaN instead.
// 2. after 0.3 s, TRANSFORM "TargetToRAS": 90 deg about z, translation (-30.5, 22.25, -98).
// 3. for SECONDS, every message received: a TRANSFORM is unpacked with the library's CRC
//    check; the others are skipped. Then it prints, per TRANSFORM device name:
//
//        COUNT <name> <messages> <seconds from first to last>
//        MATRIX <name> m00 m01 m02 m03 m10 ... m23      (the last one)
//
//    and "CRCFAIL <n>" (messages whose CRC or body check failed), "END".
//
// Prints "SENT" once the plan is sent.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "igtlClientSocket.h"
#include "igtlMessageHeader.h"
#include "igtlPointMessage.h"
#include "igtlTransformMessage.h"

using Clock = std::chrono::steady_clock;

struct Seen {
  int count = 0;
  double first = 0.0, last = 0.0;
  igtl::Matrix4x4 matrix;
};

static double now_s(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Read exactly `length` bytes before `deadline` (the socket has a short receive timeout).
// 1: read; 0: the deadline passed first; -1: the connection closed.
static int receiveAll(igtl::Socket* socket, char* data, int length, Clock::time_point deadline) {
  int got = 0;
  while (got < length) {
    if (Clock::now() > deadline) return 0;
    int r = socket->Receive(data + got, length - got, 0);
    if (r == 0) return -1;
    if (r < 0) continue;  // timeout of one receive
    got += r;
  }
  return 1;
}

static void addPoint(igtl::PointMessage::Pointer& message, const char* name, const char* group,
                     float x, float y, float z) {
  igtl::PointElement::Pointer point = igtl::PointElement::New();
  point->SetName(name);
  point->SetGroupName(group);
  point->SetRGBA(230, 230, 77, 255);
  point->SetPosition(x, y, z);
  point->SetRadius(0.0f);
  point->SetOwner("");
  message->AddPointElement(point);
}

int main(int argc, char* argv[]) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s PORT SECONDS [bad]\n", argv[0]);
    return 2;
  }
  const int port = std::atoi(argv[1]);
  const double seconds = std::atof(argv[2]);
  const bool bad = argc > 3 && std::strcmp(argv[3], "bad") == 0;
  igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
  const Clock::time_point start = Clock::now();
  while (socket->ConnectToServer("127.0.0.1", port) != 0) {
    if (now_s(start) > 5.0) {
      std::printf("NOCONNECT\n");
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  socket->SetReceiveTimeout(50);

  igtl::PointMessage::Pointer plan = igtl::PointMessage::New();
  plan->SetDeviceName("Plan");
  addPoint(plan, "F-1", "Unselected", -5.0f, 6.0f, 7.0f);
  addPoint(plan, "entry", "Selected", 12.5f, -40.25f, 7.0f);
  addPoint(plan, "Target", "Selected", bad ? std::numeric_limits<float>::quiet_NaN() : -31.75f, 18.5f, -102.0f);
  plan->Pack();
  if (!socket->Send(plan->GetPackPointer(), plan->GetPackSize())) return 1;
  std::this_thread::sleep_for(std::chrono::milliseconds(300));

  igtl::Matrix4x4 target;
  igtl::IdentityMatrix(target);
  target[0][0] = 0.0f; target[0][1] = -1.0f;
  target[1][0] = 1.0f; target[1][1] = 0.0f;
  target[0][3] = -30.5f; target[1][3] = 22.25f; target[2][3] = -98.0f;
  igtl::TransformMessage::Pointer transform = igtl::TransformMessage::New();
  transform->SetDeviceName("TargetToRAS");
  transform->SetMatrix(target);
  transform->Pack();
  if (!socket->Send(transform->GetPackPointer(), transform->GetPackSize())) return 1;
  std::printf("SENT\n");
  std::fflush(stdout);

  std::map<std::string, Seen> seen;
  int crcFailures = 0;
  const Clock::time_point receiving = Clock::now();
  const Clock::time_point deadline = receiving + std::chrono::microseconds(static_cast<long>(seconds * 1e6));
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  while (Clock::now() < deadline) {
    header->InitPack();
    int r = receiveAll(socket, static_cast<char*>(header->GetPackPointer()), header->GetPackSize(), deadline);
    if (r <= 0) break;
    header->Unpack();
    std::vector<char> skipped;
    if (std::strcmp(header->GetDeviceType(), "TRANSFORM") != 0) {
      skipped.resize(header->GetBodySizeToRead());
      if (!skipped.empty() && receiveAll(socket, skipped.data(), skipped.size(), deadline) <= 0) break;
      continue;
    }
    igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
    message->SetMessageHeader(header);
    message->AllocatePack();
    if (receiveAll(socket, static_cast<char*>(message->GetPackBodyPointer()), message->GetPackBodySize(), deadline) <= 0)
      break;
    if (!(message->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
      ++crcFailures;
      continue;
    }
    Seen& entry = seen[message->GetDeviceName()];
    const double t = now_s(receiving);
    if (entry.count == 0) entry.first = t;
    entry.last = t;
    ++entry.count;
    message->GetMatrix(entry.matrix);
  }
  for (auto& item : seen) {
    std::printf("COUNT %s %d %.6f\n", item.first.c_str(), item.second.count, item.second.last - item.second.first);
    std::printf("MATRIX %s", item.first.c_str());
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 4; ++j) std::printf(" %.6f", item.second.matrix[i][j]);
    std::printf("\n");
  }
  std::printf("CRCFAIL %d\nEND\n", crcFailures);
  std::fflush(stdout);
  socket->CloseSocket();
  return 0;
}
