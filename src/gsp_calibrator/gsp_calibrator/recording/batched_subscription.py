"""A raw subscription's callback that takes every waiting message at once (rclpy, no node)."""

from rclpy.exceptions import InvalidHandle

#: Most messages a batched callback takes at one wake-up (a bound on the work between two
#: looks at the other subscriptions).
MAX_BATCH = 1000


class BatchedCallback:
    """A raw subscription's callback: ``callback([(CDR bytes, message info), ...])`` with the
    message the executor took and every further one waiting (:data:`MAX_BATCH` at most), in
    order. Set :attr:`subscription` to the subscription it serves before it is called."""

    def __init__(self, callback):
        self.callback = callback
        self.subscription = None

    def __call__(self, raw, info):
        messages = [(raw, info)]
        subscription = self.subscription
        try:
            with subscription.handle:
                while len(messages) < MAX_BATCH:
                    taken = subscription.handle.take_message(subscription.msg_type, True)
                    if taken is None:
                        break
                    messages.append(taken)
        except InvalidHandle:  # destroyed meanwhile (the node is going down)
            pass
        self.callback(messages)
