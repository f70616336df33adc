/*
 * tls.c: the certificate and key check behind --tls-cert / --tls-key
 * (base.h "TLS files"). libwebsockets and libmicrohttpd would each refuse a
 * bad pair with a message of their own (or, for libmicrohttpd, with none);
 * this reads both files once with OpenSSL before any port opens, so a
 * missing, unreadable, non-PEM or mismatched file stops the start with an
 * error naming it.
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include "base/base.h"

static FILE *open_pem(const char *path, const char *what, error_text *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        error_set(err, "%s %s: %s", what, path, strerror(errno));
    return f;
}

int tls_check_pair(const char *cert_path, const char *key_path, error_text *err)
{
    if (!cert_path || !cert_path[0] || !key_path || !key_path[0]) {
        error_set(err, "TLS needs both --tls-cert and --tls-key");
        return -1;
    }
    FILE *f = open_pem(cert_path, "--tls-cert", err);
    if (!f)
        return -1;
    X509 *cert = PEM_read_X509(f, NULL, NULL, NULL);
    fclose(f);
    if (!cert) {
        ERR_clear_error();
        error_set(err, "--tls-cert %s: not a PEM certificate", cert_path);
        return -1;
    }
    int rc = -1;
    EVP_PKEY *key = NULL;
    if (!(f = open_pem(key_path, "--tls-key", err)))
        goto done;
    key = PEM_read_PrivateKey(f, NULL, NULL, NULL);
    fclose(f);
    if (!key) {
        error_set(err, "--tls-key %s: not a PEM private key (or one with a passphrase)", key_path);
        goto done;
    }
    if (X509_check_private_key(cert, key) != 1) {
        error_set(err, "--tls-key %s is not the key of --tls-cert %s", key_path, cert_path);
        goto done;
    }
    rc = 0;
done:
    ERR_clear_error();
    EVP_PKEY_free(key);
    X509_free(cert);
    return rc;
}
