// A stand-in for 3D Slicer during needle guidance, on the OpenIGTLink C++ library: it connects
// to spacecal (Slicer's OpenIGTLinkIF connector in client mode), sends the plan as Slicer sends
// two linear transform nodes, and logs every needle pose it receives until spacecal closes the
// connection.
//
//     igtl_reference_slicer_planner PORT SECONDS EX EY EZ TX TY TZ
//
// 1. TRANSFORM "EntryToRAS" and "TargetToRAS": identity rotation, translation (EX, EY, EZ) and
//    (TX, TY, TZ), RAS, mm (a transform node's to-parent matrix, the parent Slicer's world).
// 2. Prints "SENT", then for at most SECONDS every TRANSFORM "NeedleToTracker" received (the
//    library's CRC check on) as
//
//        POSE <seconds since SENT> x y z          (the matrix's translation, mm)
//
//    and at the end "CRCFAIL <n>", "END".
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

#include "igtlClientSocket.h"
#include "igtlMessageHeader.h"
#include "igtlTransformMessage.h"

using Clock = std::chrono::steady_clock;

static double since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Read exactly `length` bytes before `deadline`; 1: read, 0: deadline, -1: closed.
static int receiveAll(igtl::Socket* socket, char* data, int length, Clock::time_point deadline) {
  int got = 0;
  while (got < length) {
    if (Clock::now() > deadline) return 0;
    int r = socket->Receive(data + got, length - got, 0);
    if (r == 0) return -1;
    if (r < 0) continue;  // one receive's timeout
    got += r;
  }
  return 1;
}

static bool sendPoint(igtl::Socket* socket, const char* name, float x, float y, float z) {
  igtl::Matrix4x4 matrix;
  igtl::IdentityMatrix(matrix);
  matrix[0][3] = x;
  matrix[1][3] = y;
  matrix[2][3] = z;
  igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
  message->SetDeviceName(name);
  message->SetMatrix(matrix);
  message->Pack();
  return socket->Send(message->GetPackPointer(), message->GetPackSize()) != 0;
}

int main(int argc, char* argv[]) {
  if (argc < 9) {
    std::fprintf(stderr, "usage: %s PORT SECONDS EX EY EZ TX TY TZ\n", argv[0]);
    return 2;
  }
  const int port = std::atoi(argv[1]);
  const double seconds = std::atof(argv[2]);
  float p[6];
  for (int i = 0; i < 6; ++i) p[i] = static_cast<float>(std::atof(argv[3 + i]));
  igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
  const Clock::time_point start = Clock::now();
  while (socket->ConnectToServer("127.0.0.1", port) != 0) {
    if (since(start) > 30.0) {
      std::printf("NOCONNECT\n");
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  socket->SetReceiveTimeout(50);
  if (!sendPoint(socket, "EntryToRAS", p[0], p[1], p[2])) return 1;
  if (!sendPoint(socket, "TargetToRAS", p[3], p[4], p[5])) return 1;
  const Clock::time_point sent = Clock::now();
  std::printf("SENT\n");
  std::fflush(stdout);

  int crcFailures = 0;
  const Clock::time_point deadline = sent + std::chrono::microseconds(static_cast<long>(seconds * 1e6));
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  while (Clock::now() < deadline) {
    header->InitPack();
    int r = receiveAll(socket, static_cast<char*>(header->GetPackPointer()), header->GetPackSize(), deadline);
    if (r <= 0) break;
    header->Unpack();
    const bool needle = std::strcmp(header->GetDeviceType(), "TRANSFORM") == 0 &&
                        std::strcmp(header->GetDeviceName(), "NeedleToTracker") == 0;
    if (!needle) {
      std::vector<char> skipped(header->GetBodySizeToRead());
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
    igtl::Matrix4x4 matrix;
    message->GetMatrix(matrix);
    std::printf("POSE %.6f %.6f %.6f %.6f\n", since(sent), matrix[0][3], matrix[1][3], matrix[2][3]);
  }
  std::printf("CRCFAIL %d\nEND\n", crcFailures);
  std::fflush(stdout);
  socket->CloseSocket();
  return 0;
}
