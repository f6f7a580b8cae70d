"""Execute the book's notebooks over an encrypted kernel connection.

The build executes every chapter in a Jupyter kernel (myst-nb, through jupyter-cache and nbclient,
in the build's own process). By default jupyter_client connects to the kernel over TCP without
transport encryption, and ipykernel (7.x) logs "Kernel is running over TCP without encryption" for
every notebook. jupyter_client (8.x) can provision CurveZMQ keys for kernels whose kernelspec
declares support (``transport_encryption = "auto"``); nbclient creates its kernel manager without
a configuration we could pass, so this extension makes ``"auto"`` the default of
``KernelManager.transport_encryption`` for the build. With an older jupyter_client or a pyzmq
without CurveZMQ it changes nothing.
"""

from __future__ import annotations


def setup(app):
    try:
        import zmq
        from jupyter_client.manager import KernelManager
    except ImportError:
        return {"parallel_read_safe": True}
    trait = getattr(KernelManager, "transport_encryption", None)
    if trait is not None and zmq.has("curve"):
        trait.default_value = "auto"
    return {"parallel_read_safe": True, "parallel_write_safe": True}
