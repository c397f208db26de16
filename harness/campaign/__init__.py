"""Campaigns: plan the paper's experiments as runs, execute them in parallel worker processes, resume."""

from harness.campaign.plan import CampaignOptions, FlightSpec, RunSpec, plan_campaign
from harness.campaign.runner import CampaignOutcome, ExecOptions, run_campaign

__all__ = ["CampaignOptions", "CampaignOutcome", "ExecOptions", "FlightSpec", "RunSpec", "plan_campaign",
           "run_campaign"]
