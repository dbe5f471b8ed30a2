// Reference OpenIGTLink receiver on the OpenIGTLink C++ library: a server that accepts one
// client and prints the first TRANSFORM it receives, checked with the library's CRC check:
//
//     TRANSFORM <device name> m00 m01 m02 m03 m10 ... m23
//
//     igtl_reference_receiver PORT
//
// Prints "READY" once listening; exits 0 after the first TRANSFORM, 1 on a CRC failure.
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "igtlMessageHeader.h"
#include "igtlServerSocket.h"
#include "igtlTransformMessage.h"

int main(int argc, char* argv[]) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s PORT\n", argv[0]);
    return 2;
  }
  igtl::ServerSocket::Pointer server = igtl::ServerSocket::New();
  if (server->CreateServer(std::atoi(argv[1])) < 0) return 1;
  std::printf("READY\n");
  std::fflush(stdout);
  igtl::Socket::Pointer socket;
  while (!socket.IsNotNull()) socket = server->WaitForConnection(1000);
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  for (;;) {
    header->InitPack();
    if (socket->Receive(header->GetPackPointer(), header->GetPackSize()) != header->GetPackSize()) return 1;
    header->Unpack();
    if (std::strcmp(header->GetDeviceType(), "TRANSFORM") != 0) {
      socket->Skip(header->GetBodySizeToRead(), 0);
      continue;
    }
    igtl::TransformMessage::Pointer message = igtl::TransformMessage::New();
    message->SetMessageHeader(header);
    message->AllocatePack();
    socket->Receive(message->GetPackBodyPointer(), message->GetPackBodySize());
    if (!(message->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
      std::printf("CRC or body check failed for %s\n", message->GetDeviceName());
      return 1;
    }
    igtl::Matrix4x4 m;
    message->GetMatrix(m);
    std::printf("TRANSFORM %s", message->GetDeviceName());
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 4; ++j) std::printf(" %.6f", m[i][j]);
    std::printf("\n");
    std::fflush(stdout);
    return 0;
  }
}
