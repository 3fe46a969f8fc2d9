"""What this service POSTs to a job's ``webhook`` URL, as the schema's ``webhooks`` (OpenAPI 3.1): a contract for
receivers, not a route of this API (``service.webhooks`` builds and signs the deliveries)."""

from __future__ import annotations

from fastapi import APIRouter, Header

from service.schemas import WebhookPayload

router = APIRouter()


@router.post("job-event", summary="A job's event, POSTed to its webhook URL", responses={200: {
    "description": "any 2xx answer delivers the event; anything else, a redirect included (never followed), or no "
    "answer within CTP_WEBHOOK_TIMEOUT_S is a failed attempt: start and completed events are tried again with the "
    "same `webhook-id` (back-off 1 s doubling to 5 min) until CTP_WEBHOOK_RETRY_S after the event, a progress "
    "event is not"}},
    description="Sent for the events the job subscribed to (`webhook_events`). Signed as Standard Webhooks does: "
    "`webhook-signature` is `v1,` and the base64 HMAC-SHA256, keyed by the base64-decoded part of the service's "
    "`whsec_` secret after the prefix, of `{webhook-id}.{webhook-timestamp}.{body}` (the body's bytes as "
    "received). Check it, refuse a timestamp more than a few minutes off, and deduplicate by `webhook-id`: delivery "
    "is at least once and in no guaranteed order (`timestamp` in the body orders a job's events).")
def job_event(event: WebhookPayload,
              webhook_id: str = Header(alias="webhook-id", description="the event's id (`msg_...`), the same on "
                                       "every retry"),
              webhook_timestamp: int = Header(alias="webhook-timestamp", description="when this attempt was sent "
                                              "(Unix seconds)"),
              webhook_signature: str = Header(alias="webhook-signature", description="`v1,<base64 signature>`"),
              ) -> None:
    """Documentation only: never called."""
