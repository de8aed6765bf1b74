"""The operator panel in a real browser: Debian's chromium driven by Playwright, against the
simulated thesis rig booted by the cobus master.

Screenshots land in ``test-artifacts/`` (``COBUS_ARTIFACTS`` to change it). Chromium runs
headless with no network of its own (no background requests, no component updates); every
request it makes must go to the panel on 127.0.0.1, and the page must log no error (a
Content-Security-Policy violation would be one).
"""

from __future__ import annotations

import asyncio
import os
import re
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from cobus.apps.demo import IO, SERVO, ZAPI
from tests.browser import (
    CHROMIUM,
    CHROMIUM_ARGS,
    BrowserWatchdog,
    capped,
    chromium_wrapper,
    scratch,
)
from tests.test_panel_protocol import running, served
from tests.util import need, need_module

pytestmark = pytest.mark.slow


def artifacts() -> Path:
    folder = Path(os.environ.get("COBUS_ARTIFACTS", "test-artifacts"))
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def test_the_network_page_shows_the_rig_and_its_buttons_reach_the_nodes(tmp_path: Path) -> None:
    need(Path(CHROMIUM).exists(), f"no chromium at {CHROMIUM} (Debian: apt install chromium)")
    need_module("playwright", "Playwright is not installed (pip install playwright)")
    from playwright.async_api import async_playwright, expect

    requests: list[str] = []
    problems: list[str] = []

    async def main() -> None:
        async with served(tmp_path) as (demo, panel), async_playwright() as pw:
            browser = await pw.chromium.launch(
                executable_path=chromium_wrapper(Path(folder)), headless=True, args=CHROMIUM_ARGS
            )
            try:
                page = await browser.new_page(viewport={"width": 1400, "height": 900})
                page.on("request", lambda r: requests.append(r.url))
                page.on(
                    "console",
                    lambda m: problems.append(m.text) if m.type in ("error", "warning") else None,
                )
                page.on("pageerror", lambda e: problems.append(str(e)))
                page.on("dialog", lambda d: asyncio.ensure_future(d.accept()))
                await page.goto(panel.url)
                await running(demo)
                io = page.locator(f'tr[data-node="{IO}"]')
                await expect(io.locator(".nmt")).to_have_text("OPERATIONAL", timeout=10_000)
                await expect(io.locator(".led.run")).to_have_class("led run on lit")
                await expect(page.locator("#link")).to_have_text("connected")
                servo = page.locator(f'tr[data-node="{SERVO}"]')
                await expect(servo.locator(".state")).to_have_text("5 operational")
                await expect(servo.locator(".heard")).to_contain_text(" s ago")
                await expect(page.locator("#bus-load canvas").first).to_be_visible()
                # the I/O module's stop button: the node stops, its run LED single-flashes
                await io.locator('button[data-nmt="stop"]').click()
                await expect(io.locator(".nmt")).to_have_text("STOPPED", timeout=5_000)
                await expect(io.locator(".led.run")).to_have_class("led run single-flash lit")
                assert str(demo.rig.devices[IO].status()["nmt"]).upper() == "STOPPED"
                await page.screenshot(path=str(artifacts() / "panel-network.png"), full_page=True)
                # start all (no question asked) brings it back
                await page.locator('#all-nodes button[data-nmt="start"]').click()
                await expect(io.locator(".nmt")).to_have_text("OPERATIONAL", timeout=5_000)
                # the event list shows the master's word
                await expect(page.locator("#events li").first).to_be_visible()

                # faults: the alarm line shows them in turn, the Alarms page acknowledges them
                line = page.locator("#current-alarm")
                await expect(line).to_have_text("no active alarm")
                await page.get_by_role("button", name="Unplug the I/O module").click()
                await expect(line).to_contain_text(f"node {IO} master", timeout=10_000)
                await page.get_by_role("button", name="Servo drive fault").click()
                # it rotates through the active alarms, the view time (3 s) each
                await expect(line).to_contain_text("7305h", timeout=15_000)
                await expect(line).to_contain_text(f"node {IO}", timeout=10_000)
                await expect(page.locator("#alarm-count")).to_be_visible()
                await page.screenshot(path=str(artifacts() / "panel-alarm-line.png"))
                await page.get_by_role("link", name="Alarms").click()
                active = page.locator("#active-alarms tbody tr")
                await expect(active.first).to_be_visible()
                texts = await active.all_text_contents()
                assert any("7305h" in t for t in texts), texts  # the servo's EMCY
                io_alarm = active.filter(has_text="heartbeat lost")
                await io_alarm.get_by_role("button", name="Acknowledge").click()
                await expect(io_alarm.locator("td").nth(6)).to_have_text("panel")
                await page.get_by_role("button", name="Acknowledge all").click()
                await expect(page.locator("#alarm-count")).to_be_hidden()
                # the cause goes: the alarm clears and stays in the history
                await page.get_by_role("link", name="Network").click()
                await page.get_by_role("button", name="Plug it back").click()
                await expect(io.locator(".nmt")).to_have_text("OPERATIONAL", timeout=15_000)
                await page.get_by_role("link", name="Alarms").click()
                # (by kind, not by count: a loaded host may add and clear a late-TPDO alarm)
                await expect(io_alarm).to_have_count(0, timeout=10_000)
                await expect(active.filter(has_text="7305h")).to_have_count(1)  # still faulted
                history = page.locator("#alarm-history tbody tr")
                cleared = history.filter(has_text="heartbeat lost").filter(has_text="by panel")
                await expect(cleared.first.locator("td").nth(6)).not_to_have_text("active")
                await page.screenshot(path=str(artifacts() / "panel-alarms.png"), full_page=True)
                # filters: only what is still active
                await page.locator("#history-filter select").select_option("true")
                await page.get_by_role("button", name="Show").click()
                await expect(history.filter(has_text="heartbeat lost")).to_have_count(0)
                await expect(history.filter(has_text="7305h")).to_have_count(1)
                csv = await page.locator("#history-csv").get_attribute("href")
                assert csv == "/alarms.csv?active=true"

                # the servo's Drive page (it is faulted: reset it, take it over, run it)
                await page.get_by_role("link", name="Drive: servo").click()
                state = page.locator("#drive-state")
                await expect(state).to_have_text("fault")
                await expect(page.locator("#drive-alarm")).to_contain_text("7305h")
                await expect(page.locator("#drive-holder")).to_have_text(
                    "commanded by the application"
                )
                buttons = page.locator("#drive-buttons")
                await expect(buttons.get_by_role("button", name="Enable")).to_be_disabled()
                await page.get_by_role("button", name="Take over").click()
                await expect(page.locator("#drive-holder")).to_have_text(
                    "commanded from this panel"
                )
                await buttons.get_by_role("button", name="Fault reset").click()
                await expect(state).to_have_text("switch on disabled")
                await buttons.get_by_role("button", name="Enable").click()  # (confirmed)
                await expect(state).to_have_text("operation enabled")
                # in profile velocity mode: a speed, not a position (the panel sets no mode)
                await expect(page.locator("#drive-values")).to_contain_text("PROFILE_VELOCITY")
                moves = page.locator("#drive-position").get_by_role("button", name="Move")
                await expect(moves).to_be_disabled()
                await page.locator('#drive-setpoint input[name="speed"]').fill("20000")
                await page.locator('#drive-setpoint input[value="-1"]').check()
                await page.locator("#drive-setpoint").get_by_role("button", name="Set").click()
                speed = page.locator('#drive-plots [data-plot="speed"]')
                await expect(speed).to_be_visible()

                def fast(text: str | None) -> bool:
                    return text is not None and float(text) < -15_000

                for _ in range(100):  # the plotted speed follows: reverse, near the set-point
                    values = await page.locator("#drive-values dd").all_text_contents()
                    if values and fast(values[0]):
                        break
                    await asyncio.sleep(0.05)
                else:
                    raise AssertionError(f"the servo never ran at -20000: {values}")
                await page.screenshot(path=str(artifacts() / "panel-drive.png"), full_page=True)
                await page.get_by_role("button", name="QUICK STOP").click()
                # (quick stop active, then - its option code 605Ah - switch on disabled)
                await expect(state).to_have_text(re.compile("quick stop active|switch on disabled"))
                assert demo.rig.devices[SERVO].status()["state"] != "operation_enabled"
                await page.get_by_role("button", name="Give back to the application").click()
                await expect(page.locator("#drive-holder")).to_have_text(
                    "commanded by the application"
                )

                # Parameters: search, read, write (typed, checked), diff against the file
                await page.get_by_role("link", name="Parameters").click()
                form = page.locator("#param-search")
                await form.locator("select").select_option(str(SERVO))
                await form.locator('input[name="query"]').fill("device name")
                await form.get_by_role("button", name="Search").click()
                row = page.locator('#param-list tr[data-index="4104"]')  # 1008h
                await row.get_by_role("button", name="Read").click()
                await expect(row.locator("td.value")).to_have_text("cobus CiA 402 drive")
                await form.locator('input[name="query"]').fill("0x6083")
                await form.get_by_role("button", name="Search").click()
                row = page.locator('#param-list tr[data-index="24707"]')  # 6083h
                await row.locator("input").fill("-5")
                await row.get_by_role("button", name="Write").click()
                await expect(page.locator("#notice")).to_contain_text("UNSIGNED32")
                await row.locator("input").fill("12345")
                await row.get_by_role("button", name="Write").click()
                await expect(page.locator("#notice")).to_contain_text("= 12345 written")
                await row.locator("input").fill("")
                await row.get_by_role("button", name="Read").click()
                await expect(row.locator("input")).to_have_value("12345")
                await page.get_by_role("button", name="Diff against the network file").click()
                diff = page.locator("#param-diff-table tbody tr")
                await expect(diff.filter(has_text="6060h:00")).to_contain_text("same")
                set_diff = page.get_by_role("button", name="Diff against the parameter file")
                await expect(set_diff).to_be_hidden()  # (the servo has no parameter file)
                # the ZAPI: the parameter manager brought it to its file at boot
                await form.locator("select").select_option(str(ZAPI))
                status = page.locator("#param-status")
                await expect(status).to_contain_text("zapi-parameters.yml")
                # (re-parameterised at the first boot; up to date at a later one)
                await expect(status).to_contain_text(re.compile("re-parameterised|up to date"))
                await set_diff.click()
                await expect(page.locator("#param-diff-title")).to_contain_text(
                    "the parameter file zapi-parameters.yml"
                )
                await expect(diff.filter(has_text="20A8h:00")).to_contain_text("same")
                await expect(page.locator("#param-note")).to_contain_text("0 of 1 object(s)")
                await page.screenshot(
                    path=str(artifacts() / "panel-parameters.png"), full_page=True
                )

                # Trace: the live bus decoded, filtered by node and service, paused
                await page.get_by_role("link", name="Trace").click()
                records = page.locator("#trace-records tbody tr")
                await expect(records.first).to_be_visible()
                await page.locator('#trace-filter input[name="node"]').fill(str(IO))
                for kind in ("sync", "pdo", "sdo", "nmt"):
                    await page.locator(f'#trace-kinds input[value="{kind}"]').uncheck()
                await expect(records.first).to_contain_text(f"node {IO} heartbeat")
                texts = (await records.all_text_contents())[:20]
                assert all(f"node {IO}" in t for t in texts), texts
                await page.get_by_role("button", name="Pause").click()
                frozen = await records.first.text_content()
                await asyncio.sleep(0.5)
                assert await records.first.text_content() == frozen
                await expect(page.locator("#trace-note")).to_contain_text("paused")
                await page.get_by_role("button", name="Resume").click()
                await expect(records.first).not_to_have_text(frozen or "")
                await page.screenshot(path=str(artifacts() / "panel-trace.png"))
            finally:
                await browser.close()

    # (the server side capped, the browser watched: neither can run away)
    with scratch() as folder, capped(2000), BrowserWatchdog(max_rss_mb=3000) as watchdog:
        asyncio.run(asyncio.wait_for(main(), 90))
    assert not watchdog.killed, f"chromium used {watchdog.peak_mb:.0f} MB"
    assert watchdog.peak_mb > 0  # (it did watch the browser)
    hosts = {urlsplit(u).hostname for u in requests}
    assert hosts == {"127.0.0.1"}, requests
    assert problems == [], problems


def test_a_browser_reads_a_panel_with_a_token_only_through_its_address(tmp_path: Path) -> None:
    need(Path(CHROMIUM).exists(), f"no chromium at {CHROMIUM} (Debian: apt install chromium)")
    need_module("playwright", "Playwright is not installed (pip install playwright)")
    from playwright.async_api import async_playwright, expect

    async def main() -> None:
        async with (
            served(tmp_path, token="s3cret-token") as (_demo, panel),
            async_playwright() as pw,
        ):
            browser = await pw.chromium.launch(
                executable_path=chromium_wrapper(Path(folder)), headless=True, args=CHROMIUM_ARGS
            )
            try:
                page = await browser.new_page()
                assert panel.bound is not None
                await page.goto(f"http://127.0.0.1:{panel.bound[1]}/")  # (no token)
                await expect(page.locator("#link")).to_contain_text("?token=", timeout=10_000)
                await expect(page.locator("#nodes tbody tr")).to_have_count(0)
                page = await browser.new_page()
                await page.goto(panel.url)
                await expect(page.locator("#link")).to_have_text("connected", timeout=10_000)
                await expect(page.locator(f'tr[data-node="{IO}"]')).to_be_visible()
                await page.get_by_role("link", name="Alarms").click()
                csv = await page.locator("#history-csv").get_attribute("href")
                assert csv is not None and "token=s3cret-token" in csv
            finally:
                await browser.close()

    with scratch() as folder, capped(2000), BrowserWatchdog(max_rss_mb=3000) as watchdog:
        asyncio.run(asyncio.wait_for(main(), 90))
    assert not watchdog.killed, f"chromium used {watchdog.peak_mb:.0f} MB"
