"""A gRPC client that is not ours: Python grpcio, with no .proto file and no generated stubs.

It lists the services through server reflection (v1alpha and v1), builds the message classes
from the descriptors the server reflects, calls haptics.v1.LoopService/GetStatus and
ListModels, checks the token rule on ActivateModel, and calls grpc.health.v1 Check. It prints
one JSON object for the Rust test that started the server (infer-server/control-plane/tests/python_client.rs).

Usage: grpc_reflection_client.py HOST:PORT TOKEN (every haptics.v1 call needs the token; health
and reflection do not)
"""

from __future__ import annotations

import json
import sys
from typing import Any

import grpc
from google.protobuf import json_format, message_factory
from google.protobuf.descriptor_pool import DescriptorPool
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection_pb2
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)


def list_services(channel: grpc.Channel, version: str) -> list[str]:
    # v1 and v1alpha share their messages field for field; only the service name differs.
    call = channel.stream_stream(
        f"/grpc.reflection.{version}.ServerReflection/ServerReflectionInfo",
        request_serializer=reflection_pb2.ServerReflectionRequest.SerializeToString,
        response_deserializer=reflection_pb2.ServerReflectionResponse.FromString,
    )
    request = reflection_pb2.ServerReflectionRequest(list_services="")
    for response in call(iter([request]), timeout=10):
        return sorted(s.name for s in response.list_services_response.service)
    raise RuntimeError(f"no answer from reflection {version}")


class Reflected:
    """Calls unary methods with message classes built from reflected descriptors."""

    def __init__(self, channel: grpc.Channel) -> None:
        self.channel = channel
        self.pool = DescriptorPool(ProtoReflectionDescriptorDatabase(channel))

    def call(
        self,
        service: str,
        method: str,
        fields: dict[str, Any] | None = None,
        metadata: tuple[tuple[str, str], ...] = (),
    ) -> dict[str, Any]:
        desc = self.pool.FindServiceByName(service).methods_by_name[method]
        request_class = message_factory.GetMessageClass(desc.input_type)
        response_class = message_factory.GetMessageClass(desc.output_type)
        stub = self.channel.unary_unary(
            f"/{service}/{method}",
            request_serializer=request_class.SerializeToString,
            response_deserializer=response_class.FromString,
        )
        response = stub(request_class(**(fields or {})), timeout=10, metadata=metadata)
        return json_format.MessageToDict(response, preserving_proto_field_name=True)


def main() -> int:
    address, token = sys.argv[1], sys.argv[2]
    out: dict[str, Any] = {}
    with grpc.insecure_channel(address) as channel:
        out["services_v1"] = list_services(channel, "v1")
        out["services_v1alpha"] = list_services(channel, "v1alpha")
        api = Reflected(channel)
        auth = (("authorization", f"Bearer {token}"),)
        # Reads need the token too (status and models show live data and provenance).
        try:
            api.call("haptics.v1.LoopService", "GetStatus")
            out["status_without_token"] = "OK"
        except grpc.RpcError as e:
            out["status_without_token"] = e.code().name
        out["status"] = api.call("haptics.v1.LoopService", "GetStatus", metadata=auth)
        out["models"] = api.call("haptics.v1.ModelService", "ListModels", metadata=auth)
        try:
            api.call("haptics.v1.ModelService", "ActivateModel", {"name": "a.onnx"})
            out["activate_without_token"] = "OK"
        except grpc.RpcError as e:
            out["activate_without_token"] = e.code().name
        out["activate"] = api.call(
            "haptics.v1.ModelService",
            "ActivateModel",
            {"name": "a.onnx", "load_if_needed": True},
            metadata=(("authorization", f"Bearer {token}"),),
        )
        try:
            api.call(
                "haptics.v1.ModelService",
                "LoadModel",
                {"name": "../etc/passwd"},
                metadata=(("authorization", f"Bearer {token}"),),
            )
            out["bad_name"] = "OK"
        except grpc.RpcError as e:
            out["bad_name"] = e.code().name
        health = health_pb2_grpc.HealthStub(channel)
        checked = health.Check(
            health_pb2.HealthCheckRequest(service="haptics.v1.LoopService")
        )
        out["health"] = health_pb2.HealthCheckResponse.ServingStatus.Name(
            checked.status
        )
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
