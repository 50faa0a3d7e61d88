"""The design page in a real browser: Debian's Chromium driven by Selenium against a real server on loopback.

One server and one browser for the module (a few seconds per test): the paper's plant typed as MATLAB matrices into
the empty form up to the verdict and the C code download; a malformed matrix is reported at its field and nothing is
sent, while the service's own 422 is shown at the field it names; a family no controller stabilizes shows the proof;
a cancelled job; the job's URL reloads the result; the phone width. Every state is saved as a screenshot (in
``$NCS_ARTIFACTS`` when set) and checked not to be blank; the browser's console must stay free of errors.
"""

from __future__ import annotations

import os
import shutil
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from app.examples import PAPER_PLANT

from .conftest import Server, fresh_database_url

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (the test extra has it)")
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import Select, WebDriverWait  # noqa: E402

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(CHROMIUM is None or CHROMEDRIVER is None,
                       reason="chromium and chromium-driver are not installed (.ci/run installs them)"),
]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    work = tmp_path_factory.mktemp("page")
    with fresh_database_url(work) as url:
        s = Server(url, work / "server.log", NCS_WORKERS=1, NCS_CANCEL_GRACE=1.0)
        try:
            s.wait_ready()
            yield s
        finally:
            s.stop()


@pytest.fixture(scope="module")
def artifacts(tmp_path_factory) -> Path:
    where = os.environ.get("NCS_ARTIFACTS")
    path = Path(where) / "page" if where else tmp_path_factory.mktemp("page-screenshots")
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    downloads = tmp_path_factory.mktemp("downloads")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--window-size=1280,1800",
                # Nothing but loopback resolves: the page must work offline.
                "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    opts.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                           "download.prompt_for_download": False})
    service = webdriver.ChromeService(executable_path=CHROMEDRIVER)
    driver = webdriver.Chrome(service=service, options=opts)
    driver.execute_cdp_cmd("Page.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)})
    driver.downloads = downloads
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def page(browser, server):
    """The page, freshly loaded and ready; after the test, the console must hold no error."""
    browser.get(server.base + "/")
    browser.refresh()  # a clean page even when the previous test left a #job= hash
    wait(browser, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-ready") == "1")
    browser.get_log("browser")  # start each test with an empty console
    browser.allowed_console = ()
    yield browser
    errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"
              and not any(a in e["message"] for a in browser.allowed_console)]
    assert not errors, errors


def wait(driver, cond, timeout: float = 60.0):
    return WebDriverWait(driver, timeout, poll_frequency=0.1).until(cond)


def text_of(driver, element_id: str) -> str:
    return driver.find_element(By.ID, element_id).text


def shot(driver, artifacts: Path, name: str) -> Path:
    """A screenshot of the whole page, checked to show something (many colours, not one flat fill)."""
    from PIL import Image

    width = driver.get_window_size()["width"]
    driver.set_window_size(width, 800)
    height = driver.execute_script("return document.documentElement.scrollHeight")
    driver.set_window_size(width, min(max(height + 150, 800), 6000))
    path = artifacts / f"{name}.png"
    driver.save_screenshot(str(path))
    img = Image.open(path).convert("L")
    hist = img.histogram()
    assert sum(1 for c in hist if c) > 16, f"{path} looks blank"
    assert max(hist) < 0.995 * sum(hist), f"{path} is almost one colour"
    return path


def jobs_total(server) -> int:
    return httpx.get(server.base + "/v1/designs?limit=1").json()["total"]


def type_into(driver, element_id: str, text: str) -> None:
    el = driver.find_element(By.ID, element_id)
    el.clear()
    el.send_keys(text)


def matlab(mat) -> str:
    return "[" + "; ".join(" ".join(repr(v) for v in row) for row in mat) + "]"


def load_example(driver, example_id: str) -> None:
    Select(driver.find_element(By.ID, "example")).select_by_value(example_id)
    driver.find_element(By.ID, "load-example").click()


def verdict(driver, timeout: float = 90.0) -> str:
    wait(driver, lambda d: d.find_element(By.ID, "result").is_displayed() and text_of(d, "verdict"), timeout)
    return text_of(driver, "verdict")


def job_id(driver) -> str:
    url = driver.current_url
    assert "#job=" in url, url
    return url.split("#job=", 1)[1]


STATE: dict = {}


def test_paper_example_from_the_empty_form_to_the_verdict_and_the_c_code(page, server, artifacts):
    driver = page
    shot(driver, artifacts, "01-empty")
    # The paper's three modes, typed as MATLAB matrices like a new user would paste them.
    for l, (A, B) in enumerate(zip(PAPER_PLANT["A"], PAPER_PLANT["B"])):
        if l:
            driver.find_element(By.ID, "add-mode").click()
        modes = driver.find_elements(By.CSS_SELECTOR, "fieldset.mode")
        assert len(modes) == l + 1
        modes[l].find_element(By.CSS_SELECTOR, ".mat-A").send_keys(matlab(A))
        modes[l].find_element(By.CSS_SELECTOR, ".mat-B").send_keys(matlab(B))
    type_into(driver, "h", "0.1")
    driver.find_element(By.ID, "submit").click()
    text = verdict(driver)
    assert text.startswith("Stabilized for every pattern of at most 2 lost packets in a row"), text
    assert "common quadratic Lyapunov function, re-checked" in text
    jid = job_id(driver)
    job = httpx.get(f"{server.base}/v1/designs/{jid}").json()
    # What the page sent is the paper's plant, exactly.
    assert job["request"]["plant"]["A"] == PAPER_PLANT["A"] and job["request"]["plant"]["B"] == PAPER_PLANT["B"]
    assert job["request"]["n_drop"] == 3
    res = job["result"]
    assert res["outcome"] == "stabilized" and res["certificate"]["verified"]
    # The gains table shows the service's gains (to the 6 digits it prints).
    cells = driver.find_elements(By.CSS_SELECTOR, "#gains-table tbody tr")
    assert len(cells) == 3
    shown = [[float(td.text) for td in tr.find_elements(By.TAG_NAME, "td")[1:]] for tr in cells]
    np.testing.assert_allclose(shown, [K[0] for K in res["gains"]], rtol=1e-5)
    settling = driver.find_element(By.ID, "numbers").text
    assert f"{res['settling']['samples']} samples" in settling
    wait(driver, lambda d: d.find_elements(By.ID, "trace-img")
         and d.execute_script("return document.getElementById('trace-img').naturalWidth") > 0)
    # The C code: controller.zip saved by the browser holds the header and source with the gains.
    driver.find_element(By.CSS_SELECTOR, "button[data-file='controller.zip']").click()
    zips = wait(driver, lambda d: [p for p in driver.downloads.glob("*.zip") if p.stat().st_size > 0], 30)
    with zipfile.ZipFile(zips[0]) as zf:
        names = zf.namelist()
        assert any(n.endswith("_controller.c") for n in names) and any(n.endswith("_controller.h") for n in names)
        source = zf.read(next(n for n in names if n.endswith(".c"))).decode()
    k11 = res["gains"][0][0][0]
    assert f"{k11:.6g}"[:6] in source or repr(k11)[:8] in source, source[:2000]
    # The job appears in the past jobs, newest first.
    wait(driver, lambda d: jid[:8] in text_of(d, "jobs") or "stabilized" in text_of(d, "jobs"))
    first = driver.find_element(By.CSS_SELECTOR, "#jobs li a")
    assert first.get_attribute("href").endswith("#job=" + jid)
    shot(driver, artifacts, "02-paper-certified")
    STATE["paper"] = jid


def test_a_malformed_matrix_is_shown_at_its_field_and_nothing_is_sent(page, server, artifacts):
    driver = page
    before = jobs_total(server)
    mode = driver.find_element(By.CSS_SELECTOR, "fieldset.mode")
    a_field = mode.find_element(By.CSS_SELECTOR, ".mat-A")
    a_field.send_keys("[1 2; 3]")
    mode.find_element(By.CSS_SELECTOR, ".mat-B").send_keys("[1; 0]")
    err = driver.find_element(By.ID, "err-" + a_field.get_attribute("id"))
    wait(driver, lambda d: "row 2 has 1 entries, row 1 has 2" in err.text, 10)  # as you type
    assert a_field.get_attribute("aria-invalid") == "true"
    assert err.get_attribute("id") in a_field.get_attribute("aria-describedby")
    driver.find_element(By.ID, "submit").click()
    assert "nothing was sent" in text_of(driver, "err-form")
    assert driver.switch_to.active_element == a_field  # focus goes to the field to fix
    shot(driver, artifacts, "03-malformed-matrix")
    assert jobs_total(server) == before
    # What only the service knows (its limits) comes back as a 422 and is shown at the field it names.
    a_field.clear()
    a_field.send_keys("[0 1; -2 -3]")
    type_into(driver, "n_drop", "500")
    driver.allowed_console = ("/v1/designs - Failed to load resource: the server responded with a status of 422",)
    driver.find_element(By.ID, "submit").click()
    wait(driver, lambda d: "NCS_MAX_N_DROP" in text_of(d, "err-n_drop"), 20)
    assert driver.find_element(By.ID, "n_drop").get_attribute("aria-invalid") == "true"
    fix = driver.find_element(By.CSS_SELECTOR, "#err-form a")  # the service's page on how to fix it
    assert "/problems/invalid-request" in fix.get_attribute("href")
    assert jobs_total(server) == before
    shot(driver, artifacts, "04-server-422-at-field")


def test_a_family_no_controller_stabilizes_shows_the_proof(page, server, artifacts):
    driver = page
    load_example(driver, "flip")
    driver.find_element(By.ID, "submit").click()
    text = verdict(driver)
    assert text.startswith("No such controller exists: proof attached"), text
    jid = job_id(driver)
    res = httpx.get(f"{server.base}/v1/designs/{jid}").json()["result"]
    assert res["outcome"] == "infeasible" and res["certificate"]["verified"]
    proof = driver.find_element(By.ID, "proof-details")
    assert proof.get_attribute("open") is not None
    assert res["certificate"]["kind"] in proof.text and "Re-checked in float64\nyes" in proof.text
    assert not driver.find_elements(By.CSS_SELECTOR, "button[data-file='controller.zip']")  # no gains, no code
    assert driver.find_elements(By.CSS_SELECTOR, "button[data-file='job.json']")
    # Every download offered is there (the service would answer 409 for one that is not).
    for button in driver.find_elements(By.CSS_SELECTOR, "#downloads button[data-file]"):
        name = button.get_attribute("data-file")
        if name != "job.json":
            assert httpx.get(f"{server.base}/v1/designs/{jid}/{name}").status_code == 200, name
    shot(driver, artifacts, "05-infeasible-proof")


def test_a_running_job_is_cancelled(page, server, artifacts):
    driver = page
    load_example(driver, "paper")
    # The paper's plant with N = 6 and CCL over Clarabel: its first iteration alone takes seconds.
    type_into(driver, "n_drop", "6")
    Select(driver.find_element(By.ID, "method")).select_by_value("ccl")
    driver.find_element(By.CSS_SELECTOR, "details:has(#solver) summary").click()
    Select(driver.find_element(By.ID, "solver")).select_by_value("CLARABEL")
    driver.find_element(By.ID, "submit").click()
    wait(driver, lambda d: "running" in text_of(d, "progress").lower() or "Running" in text_of(d, "progress"), 30)
    cancel = driver.find_element(By.ID, "cancel")
    assert cancel.is_enabled()
    cancel.click()
    text = verdict(driver, 30)
    assert text.startswith("Cancelled"), text
    jid = job_id(driver)
    assert httpx.get(f"{server.base}/v1/designs/{jid}").json()["status"] == "cancelled"
    assert not cancel.is_enabled()
    shot(driver, artifacts, "06-cancelled")


def test_the_job_url_reloads_the_result(page, server, artifacts):
    driver = page
    jid = STATE.get("paper")
    if jid is None:  # run alone: make the job through the API
        body = {"plant": PAPER_PLANT, "n_drop": 3}
        jid = httpx.post(server.base + "/v1/designs", json=body, headers={"Prefer": "wait=60"}, timeout=90).json()["id"]
    driver.get(f"{server.base}/#job={jid}")
    driver.refresh()
    text = verdict(driver)
    assert text.startswith("Stabilized for every pattern of at most 2 lost packets"), text
    # The form shows the request the job ran, ready to change and run again.
    assert driver.find_element(By.ID, "n_drop").get_attribute("value") == "3"
    first_a = driver.find_element(By.CSS_SELECTOR, "fieldset.mode .mat-A").get_attribute("value")
    rows = [[float(v) for v in row.split()] for row in first_a.strip("[]").split(";")]
    assert rows == PAPER_PLANT["A"][0], first_a
    assert len(driver.find_elements(By.CSS_SELECTOR, "#gains-table tbody tr")) == 3
    assert driver.find_element(By.ID, "share-link").get_attribute("href").endswith("#job=" + jid)
    # The cost against the loss probability, drawn from POST /v1/channels: one point per probability.
    driver.find_element(By.ID, "cost-curve").click()
    svg = wait(driver, lambda d: d.find_elements(By.ID, "cost-svg"), 60)[0]
    label = svg.get_attribute("aria-label")
    assert label.count("p = ") == 7 and len(svg.find_elements(By.TAG_NAME, "circle")) >= 1, label
    # The margin curve: a margin job (largest N with a design) and its curve.svg.
    driver.find_element(By.ID, "margin-curve").click()
    wait(driver, lambda d: d.execute_script(
        "const i = document.querySelector(\"#figures img[alt^='Designs tried']\"); return i && i.naturalWidth > 0"), 90)
    shot(driver, artifacts, "07-job-url-reloaded")


@pytest.mark.parametrize("compressed", [False, True])
def test_a_mat_plant_file_fills_the_form(page, tmp_path, compressed):
    import scipy.io

    A = np.stack([np.array(a) for a in PAPER_PLANT["A"]], axis=2)  # n x n x r, as MATLAB's cat(3, ...)
    B = np.stack([np.array(b) for b in PAPER_PLANT["B"]], axis=2)
    path = tmp_path / "plant.mat"
    scipy.io.savemat(path, {"A": A, "B": B, "h": 0.1, "note": "a string the page skips"},
                     do_compression=compressed)
    page.find_element(By.ID, "plant-file").send_keys(str(path))
    wait(page, lambda d: len(d.find_elements(By.CSS_SELECTOR, "fieldset.mode")) == 3, 10)
    for l, mode in enumerate(page.find_elements(By.CSS_SELECTOR, "fieldset.mode")):
        text = mode.find_element(By.CSS_SELECTOR, ".mat-A").get_attribute("value")
        rows = [[float(v) for v in row.split()] for row in text.strip("[]").split(";")]
        assert rows == PAPER_PLANT["A"][l], text
    assert float(page.find_element(By.ID, "h").get_attribute("value")) == 0.1
    assert not page.find_element(By.ID, "err-plant-file").text


def test_labels_and_the_phone_width(page, server, artifacts):
    driver = page
    load_example(driver, "cartpole")
    unlabeled = driver.execute_script("""
        return Array.from(document.querySelectorAll('input, select, textarea'))
          .filter(e => e.type !== 'radio' && e.type !== 'hidden')
          .filter(e => !(e.labels && e.labels.length) && !e.getAttribute('aria-label'))
          .map(e => e.id || e.outerHTML);""")
    assert not unlabeled, unlabeled
    driver.set_window_size(390, 844)
    try:
        overflow = driver.execute_script("return document.documentElement.scrollWidth - window.innerWidth")
        assert overflow <= 1, f"the page scrolls sideways by {overflow} px at phone width"
        shot(driver, artifacts, "08-phone")
    finally:
        driver.set_window_size(1280, 1800)


def test_a_network_field_appears_when_the_schema_has_one(page, server, artifacts):
    """The `network` select is built from DesignRequest in /openapi.json; a schema with such a property is staged by
    rewriting the page's own fetch of /openapi.json, then the service's 422 for the value lands at the field."""
    driver = page
    assert not driver.find_element(By.ID, "network-row").is_displayed() or "network" in httpx.get(
        server.base + "/openapi.json").json()["components"]["schemas"]["DesignRequest"]["properties"]
    staged = driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": """
        const realFetch = window.fetch;
        window.fetch = async (url, init) => {
          const resp = await realFetch(url, init);
          if (String(url) !== '/openapi.json') return resp;
          const spec = await resp.json();
          spec.components.schemas.DesignRequest.properties.network = {
            type: 'string', enum: ['page-test-link-a', 'page-test-link-b'], default: 'page-test-link-a',
            description: 'The link the packets cross.'};
          return new Response(JSON.stringify(spec), {headers: {'Content-Type': 'application/json'}});
        };"""})
    try:
        driver.refresh()
        wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-ready") == "1")
        row = driver.find_element(By.ID, "network-row")
        assert row.is_displayed() and "The link the packets cross." in row.text
        values = [o.get_attribute("value") for o in driver.find_elements(By.CSS_SELECTOR, "#network option")]
        assert values == ["", "page-test-link-a", "page-test-link-b"]
        load_example(driver, "dc_motor")
        Select(driver.find_element(By.ID, "network")).select_by_value("page-test-link-b")
        before = jobs_total(server)
        driver.allowed_console = ("/v1/designs - Failed to load resource: the server responded with a status of 422",)
        driver.find_element(By.ID, "submit").click()
        # This service has no such value: its 422 names /network, shown at the select.
        wait(driver, lambda d: text_of(d, "err-network"), 20)
        assert driver.find_element(By.ID, "network").get_attribute("aria-invalid") == "true"
        assert jobs_total(server) == before
        shot(driver, artifacts, "09-network-field")
    finally:
        driver.execute_cdp_cmd("Page.removeScriptToEvaluateOnNewDocument", {"identifier": staged["identifier"]})


def test_keyboard_only_from_the_example_to_the_verdict(page, artifacts):
    """Tab reaches the controls in reading order, and the whole design runs without a mouse."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    driver = page
    driver.execute_script("document.querySelector('a.skip').focus()")  # the first stop of the page
    order = []
    for _ in range(60):
        ActionChains(driver).send_keys(Keys.TAB).perform()  # to whatever has focus (a file input too)
        order.append(driver.switch_to.active_element.get_attribute("id") or "")
        if order[-1] == "submit":
            break
    ids = [i for i in order if i]
    for earlier, later in [("example", "load-example"), ("load-example", "h"), ("h", "n_drop"),
                           ("n_drop", "method"), ("method", "api_key"), ("api_key", "submit")]:
        assert ids.index(earlier) < ids.index(later), ids
    example = driver.find_element(By.ID, "example")
    driver.execute_script("arguments[0].focus()", example)
    example.send_keys(Keys.ARROW_DOWN)  # the first example: the paper's motor
    assert Select(example).first_selected_option.get_attribute("value") == "paper"
    example.send_keys(Keys.TAB)
    assert driver.switch_to.active_element.get_attribute("id") == "load-example"
    driver.switch_to.active_element.send_keys(Keys.ENTER)
    wait(driver, lambda d: len(d.find_elements(By.CSS_SELECTOR, "fieldset.mode")) == 3, 10)
    driver.find_element(By.ID, "n_drop").send_keys(Keys.ENTER)  # Enter in a field submits the form
    assert verdict(driver).startswith("Stabilized for every pattern of at most 2 lost packets")
    assert driver.switch_to.active_element.get_attribute("id") == "result"  # screen readers land on the answer


def test_a_channel_report_comes_with_the_design(page, server, artifacts):
    driver = page
    load_example(driver, "dc_motor")
    Select(driver.find_element(By.ID, "channel")).select_by_value("bernoulli")
    type_into(driver, "channel_loss", "0.3")
    driver.find_element(By.ID, "submit").click()
    assert verdict(driver).startswith("Stabilized")
    job = httpx.get(f"{server.base}/v1/designs/{job_id(driver)}").json()
    sent = {k: v for k, v in job["request"]["channel"].items() if v is not None}  # the echo fills in defaults
    assert sent == {"kind": "bernoulli", "loss": 0.3}
    report = job["result"]["channel"]
    numbers = driver.find_element(By.ID, "numbers").text
    assert "Channel" in numbers and report["reason"] in numbers
    # P(a run of >= N losses starts) = (1 - p) p^N for independent losses: the page shows the service's number.
    assert report["burst_rate"] == pytest.approx(0.7 * 0.3 ** 3, rel=1e-9)
    shown = repr(float(format(report["burst_rate"], ".6g")))  # the page prints 6 significant digits
    assert f"burst rate {shown} per sample" in numbers, (shown, numbers)
    shot(driver, artifacts, "10-channel-report")


def test_a_service_with_api_keys_asks_for_one_at_its_field(browser, start_server, db_url, artifacts):
    keyed = start_server(db_url, NCS_WORKERS=1, NCS_API_KEYS="page-test-key")
    driver = browser
    driver.get(keyed.base + "/")
    wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-ready") == "1")
    wait(driver, lambda d: "API key" in text_of(d, "jobs"), 10)
    load_example(driver, "paper")
    driver.find_element(By.ID, "submit").click()
    wait(driver, lambda d: "needs an API key" in text_of(d, "err-api_key"), 20)
    assert driver.switch_to.active_element.get_attribute("id") == "api_key"
    driver.find_element(By.ID, "api_key").send_keys("page-test-key")
    driver.find_element(By.ID, "submit").click()
    assert verdict(driver).startswith("Stabilized")
    # Figures and downloads go with the key too (an <img src> or <a href> could not send it).
    wait(driver, lambda d: d.execute_script("const i = document.getElementById('trace-img'); return i && i.naturalWidth > 0"))
    wait(driver, lambda d: "paper motor" in text_of(d, "jobs"), 20)
    shot(driver, artifacts, "11-api-key")
    # Only the two requests sent before the key was given were refused.
    refused = [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    assert len(refused) == 2 and all("status of 401" in m for m in refused), refused
    driver.get("about:blank")  # let go of the server's connections before it stops
