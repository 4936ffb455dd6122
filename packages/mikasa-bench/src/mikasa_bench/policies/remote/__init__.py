"""Remote policies: ``mikasa-bench run --policy ws://HOST:PORT`` and ``mikasa-bench serve``
(openpi's websocket policy protocol, msgpack messages; ``pip install 'mikasa-bench[remote]'``).

* `mikasa_bench.policies.remote.client`: `RemotePolicy`, the client a worker builds;
* `mikasa_bench.policies.remote.wire`: the wire format (msgpack with numpy arrays, the
  observation <-> request encoding, the request check);
* `mikasa_bench.policies.remote.server`: `PolicyServer`, one policy instance per connection.

Import names from those modules; this package file imports nothing (the server builds
policies with `mikasa_bench.policies.loading`, which loads the client).
"""
